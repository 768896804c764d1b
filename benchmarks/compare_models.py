#!/usr/bin/env python
"""Two or more trained models, paired per map on real strips with ground truth: is the first
better or worse than each other one beyond noise? The figure behind "make it the default only
if it beats the shipped model on renderings beyond noise with no map worse beyond noise".

Every strip of each folder is read as ``svbrdf-bench run --test-data`` reads it (the whole
image resized to the models' resolution), each model's network maps (no refinement) are
scored against the truth (RMSE of each map's stored encoding and of renderings under the 6
evaluation views), and the scores are averaged per source material (a Des18 strip counts for
both of its materials; an unseen-dev file is a material). Then, for the first model against
each other one, the paired difference per map over materials with its 95% bootstrap interval,
in % of the other model's mean: "beats" or "worse" when the whole interval is on one side of 0,
else "within noise".

Usage::

    .venv/bin/python benchmarks/compare_models.py DATA/unseen-dev DATA/des18-dev \\
        --models new.pt,pretrained:ours-general-cpu,pretrained:ours-mix-cpu
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

KEYS = ("normal", "diffuse", "roughness", "specular", "render")


def scores(model, test) -> list[tuple[tuple[str, ...], dict[str, float]]]:
    """``(materials, {key: RMSE})`` per strip of ``test``, the model's network maps, scored by
    svbrdf-bench's own :func:`svbrdf_bench.metrics.evaluate`."""
    from svbrdf_bench.metrics import evaluate
    from svbrdf_render import SVBRDF

    rows = []
    for i in range(len(test)):
        sample = test[i]
        with torch.no_grad():
            pred = model.generator(sample["input"][None].float())
        truth = SVBRDF.unpack(sample["maps"][None], validate=False)
        figures = {
            k.split("/", 1)[1]: float(v[0]) for k, v in evaluate(pred, truth).items() if k.startswith("rmse/")
        }
        rows.append((test.groups[i] if test.groups else (test.sample_names[i],), figures))
    return rows


def report(name: str, labels: list[str], results: list) -> str:
    from svbrdf_bench.metrics import paired_difference

    first = results[0]
    lines = [f"### {name}: {len(first.materials)} materials (RMSE, mean over materials)", ""]
    lines += ["| model | " + " | ".join(KEYS) + " |", "| --- |" + " ---: |" * len(KEYS)]
    for label, r in zip(labels, results, strict=True):
        lines.append(f"| {label} | " + " | ".join(f"{r.mean[k]:.4f}" for k in KEYS) + " |")
    lines += ["", f"{labels[0]} against each, paired over materials, in % of the other's mean:", ""]
    lines += ["| against | " + " | ".join(KEYS) + " |", "| --- |" + " ---: |" * len(KEYS)]
    for label, r in zip(labels[1:], results[1:], strict=True):
        cells = [paired_difference(first.values(k), r.values(k)).percent_of(r.mean[k]) for k in KEYS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="folders of Des18-layout strips with ground truth")
    ap.add_argument("--models", required=True, help="comma-separated model files or pretrained[:NAME], "
                    "the one judged first")  # fmt: skip
    args = ap.parse_args(argv)
    import svbrdf_models as sm
    from svbrdf_bench.testset import test_set
    from svbrdf_train.data.real.materials import per_material

    torch.set_num_threads(1)
    labels = [s.strip() for s in args.models.split(",") if s.strip()]
    if len(labels) < 2:
        sys.exit(
            "compare_models: error: --models needs at least two models, the first judged against the rest"
        )
    models = [sm.load_model(s) for s in labels]
    resolutions = {m.resolution for m in models}
    if len(resolutions) != 1:
        sys.exit(f"compare_models: error: the models run at different resolutions {sorted(resolutions)}")
    for folder in args.folders:
        test = test_set(folder, models[0].resolution, 0)
        results = [per_material(scores(m, test)) for m in models]
        print(report(folder.name, labels, results))


if __name__ == "__main__":
    main()
