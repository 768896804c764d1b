#!/usr/bin/env bash
# A prepared device check of issue 44 (not yet run: on 2026-11-30 no machine was lent): the
# shots capture on CUDA, `svbrdf-models predict --shots --device cuda`, through
# benchmarks/shots_sweep.py on 3 unseen-dev materials (the shipped rule and a flat normal
# prior), and one photo's `predict --device cuda`; figures to compare with the CPU's in
# docs/measured-shots.md ("Clipped pixels as lower bounds").
#
# The tracked tree is larger than the 64 MiB a device call sends: move the superseded weights
# and the fits' stores out of it for the call (and back after). Prepare, from the repository
# root on the CPU machine:
#   echo /.gpu44/ >> .git/info/exclude
#   .venv/bin/python -m pip install --no-deps --no-index --no-build-isolation --target .gpu44/site \
#       packages/svbrdf-render packages/svbrdf-models packages/svbrdf-train packages/svbrdf-bench
#   find .gpu44/site -name '*.pt' -delete   # the shipped weights travel in the tree; link them:
#   ln -s ../../../../packages/svbrdf-models/src/svbrdf_models/pretrained/ours-general-cpu.pt \
#       .gpu44/site/svbrdf_models/pretrained/
#   cp -r DATA/unseen-dev .gpu44/unseen-dev
#   .venv/bin/python benchmarks/shots_sweep.py .gpu44/unseen-dev --limit 3 --out .gpu44/sweep --set kept
#     (makes the photos, .gpu44/sweep/unseen-dev/photos, and the CPU's figures)
# then run(command="bash benchmarks/gpu_shots.sh", carry=[".gpu44/site", ".gpu44/unseen-dev",
#   ".gpu44/sweep/unseen-dev/photos"], timeout_s=420).
set -uo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:?set OUT to the folder the results go to}"
export PYTHONPATH=$PWD/.gpu44/site PYTHONUNBUFFERED=1
python3 -c "import torch; print(torch.__version__, torch.cuda.get_device_name())"
mkdir -p .gpu44/run/unseen-dev && cp -r .gpu44/sweep/unseen-dev/photos .gpu44/run/unseen-dev/
t0=$(date +%s)
python3 benchmarks/shots_sweep.py .gpu44/unseen-dev --limit 3 --device cuda --out .gpu44/run \
    --set kept --set flat:relief=0 > "$OUT/sweep.log" 2>&1
echo "sweep rc $? in $(( $(date +%s) - t0 )) s"
grep -v "^\.gpu\|^no --model\|^generator\|torch thread" "$OUT/sweep.log" | tail -30
cp .gpu44/run/*.json "$OUT/" 2>/dev/null
python3 -m svbrdf_models predict .gpu44/run/unseen-dev/photos/ambientcg_Bark014/today.jpg --device cuda \
    --relit none -o "$OUT/one" > "$OUT/one.log" 2>&1
echo "one photo rc $?"
tail -4 "$OUT/one.log"
