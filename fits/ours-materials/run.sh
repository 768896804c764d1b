#!/usr/bin/env bash
# The long fit of issue 34: ours-materials at the cpu size, from the shipped procedural model,
# 20% procedural and 80% real-train strips (fold 1/5 held out: val_fold/ and the normal scale),
# unseen-dev watched as val_real/ and never chosen on, 240 minutes of CPU time on one thread.
# Run from the repository root:  fits/ours-materials/run.sh [start|resume]
# State (checkpoint, MLflow store, log) stays in this folder so that a later session resumes it;
# the strip shard is made again from DATA/real-train when missing (the same bytes every time).
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR=fits/ours-materials
DATA="${SVBRDF_DATA:-$(cd .. && pwd)/shared/data}"
SHARD=$DIR/real-train-256.h5
WEIGHT="${WEIGHT:-0.8}"
[ -f "$SHARD" ] || .venv/bin/svbrdf-train data strips "$DATA/real-train" --out "$SHARD" --tile 256
export MLFLOW_TRACKING_URI="sqlite:///$DIR/mlflow.db" OMP_NUM_THREADS=1
mode="${1:-start}"
if [ "$mode" = start ]; then
    args=(--recipe ours-materials --size cpu --init pretrained --data "$SHARD" --out "$DIR/out"
          --experiment shipped --max-minutes 240
          --set "data.mix=[{source: procedural, weight: $(python3 -c "print(round(1 - $WEIGHT, 3))")}, {source: materials, weight: $WEIGHT, fold: '1/5'}]"
          --set data.count=400000 --set train.epochs=1 --set data.validation=16
          --set train.validate_every=500 --set train.checkpoint_every=250
          --set "data.real_validation=$DATA/unseen-dev")
else
    args=(--out "$DIR/out" --resume)
fi
setsid nohup nice .venv/bin/svbrdf-train fit "${args[@]}" -q >> "$DIR/fit.log" 2>&1 < /dev/null &
echo "fit started (pid $!): tail -f $DIR/fit.log"
