#!/usr/bin/env python
"""Judge trained model files on real strips they never learnt, beside the quick ``ours`` and
the constant-map baselines: the figures of the shipped model's card.

Each model file lists in its provenance the real strips it trained on. Its judging strips
are the other strips of the Des18 folder ``DATA`` (so a model trained on the even strips of
des18-dev is judged on the odd ones; a procedural-only model on all of them). For each model:
``svbrdf-bench run --preset quick --models ours --from-models FILE --test-data JUDGE``, which
also trains the quick ``ours`` (2 minutes, procedural) and scores the ``mean`` and ``photo``
baselines on the same strips (``OUT/report-K``). Then:

1. the first model alone on its judging strips: RMSE per map and of the renderings, 95%
   bootstrap intervals, and the paired difference against ``mean``;
2. all models pooled (each strip judged once, by the model that never saw it: with two
   complementary folds, a cross-validated figure for the recipe), the same way.

Usage::

    .venv/bin/python benchmarks/shipped_model.py ../shared/data/des18-dev \\
        --models fold0.pt,fold1.pt -o shipped-report
    .venv/bin/python benchmarks/shipped_model.py DATA --models fold0.pt,fold1.pt -o OUT --judge-only

Runs go to MLflow (``MLFLOW_TRACKING_URI``, else ``./mlflow.db``), experiment ``shipped-model``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from real_mix import strips  # this folder's: the strip files of a Des18 folder

COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")
QUICK, MEAN, PHOTO = "ours", "mean", "photo"


def judging_folder(data: Path, model: str, out: Path) -> Path:
    """A folder of links to the strips of ``data`` the model did not train on."""
    import svbrdf_models as sm
    from svbrdf_bench.references import trained_files

    seen = trained_files(sm.load_model(model))
    folder = out / "judge"
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    for strip in strips(data):
        if strip.name not in seen:
            (folder / strip.name).symlink_to(strip.resolve())
    return folder


def bench(model: str, judge: Path, out: Path, env: dict) -> str:
    """Run the benchmark on one model; its parent MLflow run."""
    cmd = [
        sys.executable, "-m", "svbrdf_bench", "run", "--preset", "quick", "--models", QUICK,
        "--from-models", model, "--test-data", str(judge), "--experiment", "shipped-model", "-o", str(out),
    ]  # fmt: skip
    print(" ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, env=env, check=True)
    return json.loads((out / "results.json").read_text())["parent_run"]


def scores_of(parent: str) -> dict[str, dict[str, list[float]]]:
    """Per-image RMSE of each row of a benchmark, keyed by role: model, ours, mean, photo."""
    from svbrdf_bench.report import build_report

    out: dict[str, dict[str, list[float]]] = {}
    for entry in build_report(parent).models:
        role = entry.label if entry.label in (QUICK, MEAN, PHOTO) else "model"
        out[role] = {c: entry.per_sample[f"rmse/{c}"].tolist() for c in COLUMNS}
    return out


def table(scores: dict[str, dict[str, list[float]]], labels: dict[str, str]) -> str:
    from svbrdf_bench.metrics import bootstrap_ci, paired_difference

    head = "| model | " + " | ".join(COLUMNS) + " |\n| --- |" + " ---: |" * len(COLUMNS)
    rows = [head]
    for role, label in labels.items():
        cells = []
        for c in COLUMNS:
            m, lo, hi = bootstrap_ci(scores[role][c])
            cells.append(f"{m:.4f} [{lo:.4f}, {hi:.4f}]")
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    rows += [
        "",
        "Against `mean` (paired, % of `mean`'s RMSE; beats / worse: the interval excludes 0):",
        "",
        head,
    ]
    for role, label in labels.items():
        if role == MEAN:
            continue
        cells = []
        for c in COLUMNS:
            base = sum(scores[MEAN][c]) / len(scores[MEAN][c])
            cells.append(paired_difference(scores[role][c], scores[MEAN][c]).percent_of(base))
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def pooled(parts: list[dict[str, dict[str, list[float]]]]) -> dict[str, dict[str, list[float]]]:
    out: dict[str, dict[str, list[float]]] = {}
    for part in parts:
        for role, columns in part.items():
            for c, values in columns.items():
                out.setdefault(role, {}).setdefault(c, []).extend(values)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data", type=Path, help="a Des18 folder of strips with ground truth (e.g. des18-dev)")
    p.add_argument(
        "--models", required=True, help="model files, comma-separated; the first is reported alone"
    )
    p.add_argument("-o", "--out", type=Path, default=Path("shipped-report"))
    p.add_argument("--judge-only", action="store_true", help="reuse OUT/report-K from an earlier run")
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(
            f"shipped_model: error: {args.data}: not a folder; give a Des18 folder of strips", file=sys.stderr
        )
        return 2
    models = [m for m in args.models.split(",") if m]
    env = dict(os.environ)
    parts, counts = [], []
    for k, model in enumerate(models):
        out = args.out / f"report-{k}"
        judge = judging_folder(args.data, model, args.out / f"fold-{k}")
        counts.append(len(strips(judge)))
        print(f"{model}: judged on {counts[-1]} strips it never trained on ({judge})", flush=True)
        if args.judge_only:
            parent = json.loads((out / "results.json").read_text())["parent_run"]
        else:
            parent = bench(model, judge, out, env)
        parts.append(scores_of(parent))
    labels = {"model": "shipped model", QUICK: "`ours`, quick (2 min, procedural)", MEAN: "`mean` (baseline)"}
    labels[PHOTO] = "`photo` (baseline)"
    text = [f"## {models[0]} on the {counts[0]} strips it never trained on", "", table(parts[0], labels)]
    if len(parts) > 1:
        labels["model"] = "fold models (each strip judged by the one that never saw it)"
        text += [
            "",
            f"## All {len(models)} models pooled: {sum(counts)} strips",
            "",
            table(pooled(parts), labels),
        ]
    report = "\n".join(text) + "\n"
    (args.out / "shipped.md").write_text(report)
    print("\n" + report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
