#!/usr/bin/env bash
# The issue-24 long fit: ours-general, cpu size, one thread, code frozen at the fitsnap worktree.
set -euo pipefail
cd /work/fit
SNAP=/work/fitsnap/packages
export PYTHONPATH=$SNAP/svbrdf-render/src:$SNAP/svbrdf-models/src:$SNAP/svbrdf-train/src:$SNAP/svbrdf-bench/src
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
export MLFLOW_TRACKING_URI=sqlite:////work/fit/mlflow.db
exec nice -n 10 /work/main/.venv/bin/svbrdf-train fit \
    --recipe ours-general --size cpu --max-minutes 240 --out general --experiment shipped \
    --set data.count=400000 --set train.epochs=1 --set optim.decay_every_samples=50000 \
    --set train.validate_every=1000 --set train.checkpoint_every=250 \
    --set data.real_validation=/work/shared/data/unseen-dev "$@"
