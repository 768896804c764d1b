#!/usr/bin/env bash
# Stage 3 of issue 46 (fits/ours-real191/run.sh mixed: the `phone` and `handheld` captures mixed
# sample by sample over procedural samples and the 191 real materials, fold 1/5 kept out) on a
# GPU machine without mlflow: batch 32, samples made on the device (data.generate=device),
# the fold validated on 64 samples, not tracked (--no-track). Ran once on an H200 on 2026-11-29
# for 6.5 minutes: fit.log, best.json and last.json beside this file.
#
# The device tool sends the working tree (64 MiB at most), so this folder's preparation is
# small: from the repository root, on the CPU machine,
#   mkdir -p .gpu46 && echo /.gpu46/ >> .git/info/exclude
#   .venv/bin/svbrdf-train data strips fits/ours-real191/strips --out .gpu46/real-191-128.h5 --tile 128
#   .venv/bin/python -m pip install --no-deps --no-index --no-build-isolation --target .gpu46/site \
#       packages/svbrdf-render packages/svbrdf-models packages/svbrdf-train
#   find .gpu46/site -name '*.pt' -delete; cp -r DATA/unseen-dev .gpu46/unseen-dev
# (128 px tiles: 12 MiB instead of the 256 px shard's 51; the windows the fit cuts are read
# from them at the training resolution, so small windows are upsampled more than on the CPU),
# the pretrained weights and other fits' stores moved out of the tree for the call, and
#   fits/ours-real191/gpu/run.sh /tmp/run cuda 6.5   (the device call, carrying .gpu46)
# usage: run.sh OUTDIR DEVICE MINUTES [extra fit flags]; BATCH and NVAL override 32 and 64.
set -euo pipefail
out=$1; dev=$2; minutes=$3; shift 3
mix="[{source: procedural, weight: 0.25, capture: phone}, {source: procedural, weight: 0.25, capture: handheld},"
mix+=" {source: materials, weight: 0.25, fold: '1/5', capture: handheld},"
mix+=" {source: materials, weight: 0.25, fold: '1/5', capture: phone}]"
PYTHONPATH=.gpu46/site exec python3 -u -m svbrdf_train fit --recipe ours-materials --size cpu \
  --init fits/ours-real191/out/best.pt --data .gpu46/real-191-128.h5 --out "$out" --no-track \
  --device "$dev" --max-minutes "$minutes" --keep-best val_fold/rmse/render --set "data.mix=$mix" \
  --set data.balance=kind --set "data.albedo_prior=[0.12, 0.7]" --set data.count=4000000 \
  --set train.epochs=1 --set data.generate=device --set train.batch="${BATCH:-32}" \
  --set data.real_validation=.gpu46/unseen-dev --set data.validation="${NVAL:-64}" \
  --set train.validate_every=500 --set train.checkpoint_every=2000 "$@"
