#!/usr/bin/env bash
# After the long fit of issue 34 has finished (fits/ours-materials/fit.log says "finished"):
# export it, choose its relief scale on the held-out real-train fold (never on unseen-dev),
# and judge it beside the shipped models and the baselines. Writes fits/ours-materials/judge/.
# Run from the repository root: fits/ours-materials/finish.sh   (about 20 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR=fits/ours-materials
OUT=$DIR/judge
DATA="${SVBRDF_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"
export OMP_NUM_THREADS=1 MLFLOW_TRACKING_URI="sqlite:///$OUT/bench.db"
.venv/bin/svbrdf-train export "$DIR/out" -o "$OUT/raw.pt" --force
# The relief scale with the lowest normal error on the held-out fold 1/5 of real-train.
.venv/bin/python benchmarks/normal_scale.py "$DATA/real-train" --fold 1/5 --model "$OUT/raw.pt" \
    --apply "$OUT/ours-materials-cpu.pt" | tee "$OUT/normal_scale_fold.txt"
# Reported, not chosen on: per material, on unseen-dev.
.venv/bin/python benchmarks/normal_scale.py "$DATA/unseen-dev" --model "$OUT/raw.pt" | tee "$OUT/normal_scale_unseen.txt"
.venv/bin/svbrdf-bench run --models ours \
    --from-models "$OUT/ours-materials-cpu.pt,$OUT/raw.pt,pretrained:ours-general-cpu,pretrained:ours-mix-cpu" \
    --test-data "$DATA/unseen-dev" -o "$OUT/unseen-dev" | tee "$OUT/unseen-dev.txt"
.venv/bin/svbrdf-bench run --models ours --from-models "$OUT/ours-materials-cpu.pt,pretrained:ours-general-cpu" \
    --test-data "$DATA/des18-dev" -o "$OUT/des18-dev" | tee "$OUT/des18-dev.txt"
# The default rule: beats ours-general-cpu on renderings beyond noise, no map worse beyond noise.
.venv/bin/python benchmarks/compare_models.py "$DATA/unseen-dev" "$DATA/des18-dev" \
    --models "$OUT/ours-materials-cpu.pt,pretrained:ours-general-cpu,pretrained:ours-mix-cpu" | tee "$OUT/compare.txt"
.venv/bin/python benchmarks/real_photos.py "$DATA/real-dev" \
    --models "$OUT/ours-materials-cpu.pt,pretrained:ours-general-cpu" -o "$OUT/real-photos.png" | tee "$OUT/real_photos.txt"
.venv/bin/python benchmarks/real_photos.py "$DATA/real-dev" --refine 100 --size 256 \
    --models "$OUT/ours-materials-cpu.pt,pretrained:ours-general-cpu" | tee "$OUT/real_photos_refined.txt"
echo "judged: $OUT"
