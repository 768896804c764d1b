#!/usr/bin/env bash
# The prepared GPU session of issue 37, for the `device` tool (one call, at most 10 minutes).
# The reference data does not travel to the device: make a strip shard here and carry it,
#   echo /.gpu/ >> .git/info/exclude
#   .venv/bin/svbrdf-train data strips DATA/real-train --out .gpu/real-train-384.h5 --tile 384
#   run(command="STRIPS=.gpu/real-train-384.h5 bash benchmarks/gpu_session.sh", carry=[".gpu"], timeout_s=600)
# (384 px tiles, 37 MB, within the 64 MB a call carries; 512 px would be 66 MB). Installs the
# workspace packages into the device's Python (it has torch, click, h5py, PyYAML, numpy,
# Pillow; no MLflow: the fits run --no-track; wheels carried in .whl are installed first), then
# benchmarks/gpu_session.py: the option ladder for ours, the ablations under the best options,
# and the best configuration trained for the minutes left; everything lands in $OUT.
# Dry run on a CPU: OUT=/tmp/dry DEVICE=cpu SIZE=smoke BUDGET=2 bash benchmarks/gpu_session.sh
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:?set OUT to the folder the results go to}"
DEVICE="${DEVICE:-cuda}" SIZE="${SIZE:-paper}" BUDGET="${BUDGET:-8.5}"
PY="${PYTHON:-python3}"
mkdir -p "$OUT"
if [ -d .whl ]; then  # wheels carried for what the device lacks (pypng)
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    export PYTHONPATH="/tmp/site${PYTHONPATH:+:$PYTHONPATH}"
fi
if ! "$PY" -c "import svbrdf_train" 2>/dev/null; then
    "$PY" -m pip install -q --no-deps --no-build-isolation --no-index \
        -e packages/svbrdf-render -e packages/svbrdf-models -e packages/svbrdf-train
fi
extra=()
if [ -n "${STRIPS:-}" ]; then  # without them the training recipe is ours-general (procedural only)
    extra=(--data "$STRIPS")
fi
export PYTHONUNBUFFERED=1
"$PY" benchmarks/gpu_session.py --device "$DEVICE" --size "$SIZE" --budget "$BUDGET" --out "$OUT" \
    "${extra[@]}" "$@" 2>&1 | tee "$OUT/session.log"
