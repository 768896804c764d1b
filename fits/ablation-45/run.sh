#!/usr/bin/env bash
# The fits of issue 45's measurement: the paper's ablation question at the cpu size, on the
# quick preset's terms (data.count=20000, validation every 25 steps), one fit per recipe and seed
# with snapshots at 2, 8 and 32 minutes of CPU time (train.clock cpu: a busy machine slows the
# fit instead of eating its budget), one torch thread, niced, in the background.
#   recipes: ours, no-attn, no-attn-wide (no-attn at ours' parameter count)
#   seeds:   0, 1, 2 (train.seed = data.seed = s: weights, data order and noise)
# Seed-major order, so that a stop part-way leaves whole seeds of all three recipes. Each fit
# that stops in the middle (session end, Ctrl-C) is resumed from its last checkpoint by running
# this script again; a finished fit (its DONE file) is skipped. The fits are procedural only, so
# DATA/des18-dev and DATA/unseen-dev are both test sets none of them saw; they are scored with
#   MLFLOW_TRACKING_URI=sqlite:///fits/ablation-45/mlflow.db svbrdf-bench run \
#     --from-runs ours,no-attn,no-attn-wide --seeds 3 --minutes 2,8,32 --test-data DATA/unseen-dev
# Run from the repository root: fits/ablation-45/run.sh [--foreground]. SEEDS="0 1" limits a run to
# those seeds, so that two runs on two cores share the work without meeting on one fit:
#   SEEDS="0 1" fits/ablation-45/run.sh; SEEDS=2 fits/ablation-45/run.sh
# All nine fits run the code of one commit (CODE_REV), checked out beside the repository
# (CODE_TREE) and put first on PYTHONPATH, so that work on the packages meanwhile (and issue
# 48's sample change) reaches none of them; the state (checkpoints, MLflow store) stays here.
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR=fits/ablation-45
CODE_REV=e3590a5
CODE_TREE="${CODE_TREE:-$(pwd)/../frozen-45}"
if [ ! -d "$CODE_TREE" ]; then
    git worktree add -q "$CODE_TREE" "$CODE_REV"
fi
[ "$(git -C "$CODE_TREE" rev-parse --short=7 HEAD)" = "$CODE_REV" ] || { echo "$CODE_TREE is not at $CODE_REV"; exit 2; }
src="$CODE_TREE/packages"
export PYTHONPATH="$src/svbrdf-render/src:$src/svbrdf-models/src:$src/svbrdf-train/src:$src/svbrdf-bench/src"
export MLFLOW_TRACKING_URI="sqlite:///$DIR/mlflow.db" OMP_NUM_THREADS=1
export SEEDS="${SEEDS:-0 1 2}"
if [ "${1:-}" != --foreground ]; then
    setsid nohup nice "$0" --foreground >> "$DIR/fit.log" 2>&1 < /dev/null &
    echo "fits started (pid $!): tail -f $DIR/fit.log"
    exit 0
fi
for seed in ${SEEDS:-0 1 2}; do
    for recipe in ours no-attn no-attn-wide; do
        out="$DIR/$recipe-s$seed"
        if [ -f "$out/DONE" ]; then continue; fi
        echo "== $(date -u +%FT%TZ) $recipe seed $seed"
        if [ -f "$out/last.json" ]; then
            .venv/bin/svbrdf-train fit --out "$out" --resume -q
        else
            .venv/bin/svbrdf-train fit --recipe "$recipe" --size cpu --out "$out" --force \
                --experiment issue-45 --run-name "$recipe" --max-minutes 32 \
                --set train.validate_every=25 --set data.count=20000 \
                --set "train.snapshot_minutes=[2, 8, 32]" \
                --set "train.seed=$seed" --set "data.seed=$seed" -q
        fi
        touch "$out/DONE"
    done
done
echo "== $(date -u +%FT%TZ) all fits done"
