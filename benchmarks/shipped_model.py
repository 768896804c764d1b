#!/usr/bin/env python
"""Judge trained model files on real strips they never learnt, beside the quick ``ours`` and
the constant-map baselines: the figures of the shipped model's card.

Each model file lists in its provenance the real strips it trained on. Its judging strips
are the other strips of each folder ``DATA`` (so a model trained on the even strips of
des18-dev is judged on the odd ones; a procedural-only model on all of them; on unseen-dev,
whose materials no Des18 strip shows, on all). For each folder and model:
``svbrdf-bench run --preset quick --models ours --from-models FILE --test-data JUDGE``, which
also trains the quick ``ours`` (2 minutes, procedural) and scores the ``mean`` and ``photo``
baselines on the same strips (``OUT/report-K``). Then:

1. the first model alone on its judging strips: RMSE per map and of the renderings, 95%
   bootstrap intervals, and the paired difference against ``mean``;
2. all models pooled (each strip judged once, by the model that never saw it: with
   complementary folds, a cross-validated figure for the recipe), the same way.

Every figure is a mean *per source material* (:mod:`svbrdf_train.data.real.materials`): a Des18
strip counts for both materials its name gives, an unseen-dev file is one material; intervals
and the paired differences resample materials. Note that folds split by strip (even/odd) judge
on materials the model trained on; ``svbrdf-train data folds`` makes folds that do not.

Usage::

    .venv/bin/python benchmarks/shipped_model.py DATA/des18-dev \\
        --models fold0.pt,fold1.pt -o shipped-report
    .venv/bin/python benchmarks/shipped_model.py DATA --models fold0.pt,fold1.pt -o OUT --judge-only
    .venv/bin/python benchmarks/shipped_model.py DATA/unseen-dev DATA/des18-dev --models pretrained

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


#: A benchmark's per-strip scores: the strips' names, and per role {column: RMSE per strip}.
Scores = tuple[list[str], dict[str, dict[str, list[float]]]]


def scores_of(parent: str, judge: Path) -> Scores:
    """Per-strip RMSE of each row of a benchmark, keyed by role (model, ours, mean, photo), and
    the strips' names (as the benchmark recorded them; older runs: the judging folder's)."""
    from svbrdf_bench.report import build_report

    report = build_report(parent)
    out: dict[str, dict[str, list[float]]] = {}
    for entry in report.models:
        role = entry.label if entry.label in (QUICK, MEAN, PHOTO) else "model"
        out[role] = {c: entry.per_sample[f"rmse/{c}"].tolist() for c in COLUMNS}
    return report.sample_names or [s.name for s in strips(judge)], out


def per_material_values(scores: Scores) -> tuple[dict[str, dict[str, list[float]]], int]:
    """Per role and column, the per-material means (materials sorted); and the number of materials."""
    from svbrdf_train.data.real.materials import per_material

    names, by_role = scores
    out: dict[str, dict[str, list[float]]] = {}
    count = 0
    for role, columns in by_role.items():
        pm = per_material((name, {c: columns[c][i] for c in COLUMNS}) for i, name in enumerate(names))
        out[role] = {c: pm.values(c) for c in COLUMNS}
        count = len(pm.materials)
    return out, count


def table(scores: dict[str, dict[str, list[float]]], labels: dict[str, str]) -> str:
    """The tables of per-material values ``scores`` (role -> column -> one value per material)."""
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
        "Against `mean` (paired over materials, % of `mean`'s RMSE; beats / worse: the interval "
        "excludes 0):",
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


def pooled(parts: list[Scores]) -> Scores:
    """The strips of every part together (each judged by the one model that never saw it)."""
    names: list[str] = []
    out: dict[str, dict[str, list[float]]] = {}
    for part_names, part in parts:
        names += part_names
        for role, columns in part.items():
            for c, values in columns.items():
                out.setdefault(role, {}).setdefault(c, []).extend(values)
    return names, out


def report_folder(data: Path, models: list[str], out: Path, judge_only: bool, env: dict) -> list[str]:
    """The Markdown sections of one folder of strips."""
    parts, counts = [], []
    for k, model in enumerate(models):
        report = out / f"report-{k}"
        judge = judging_folder(data, model, out / f"fold-{k}")
        counts.append(len(strips(judge)))
        print(f"{model}: judged on {counts[-1]} strips of {data} it never trained on ({judge})", flush=True)
        if judge_only:
            parent = json.loads((report / "results.json").read_text())["parent_run"]
        else:
            parent = bench(model, judge, report, env)
        parts.append(scores_of(parent, judge))
    labels = {"model": "shipped model", QUICK: "`ours`, quick (2 min, procedural)", MEAN: "`mean` (baseline)"}
    labels[PHOTO] = "`photo` (baseline)"
    values, materials = per_material_values(parts[0])
    text = [
        f"## {data.name}: {models[0]} on the {counts[0]} strips ({materials} materials) it never trained on",
        "",
        "RMSE, mean over materials [95% bootstrap over materials]:",
        "",
        table(values, labels),
    ]
    if len(parts) > 1:
        labels["model"] = "fold models (each strip judged by the one that never saw it)"
        values, materials = per_material_values(pooled(parts))
        text += [
            "",
            f"## {data.name}: all {len(models)} models pooled: {sum(counts)} strips of {materials} materials",
            "",
            table(values, labels),
        ]
    return text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "data", type=Path, nargs="+", help="folders of strips with ground truth (des18-dev, unseen-dev)"
    )
    p.add_argument(
        "--models", required=True, help="model files, comma-separated; the first is reported alone"
    )
    p.add_argument("-o", "--out", type=Path, default=Path("shipped-report"))
    p.add_argument("--judge-only", action="store_true", help="reuse OUT/report-K from an earlier run")
    args = p.parse_args(argv)
    for data in args.data:
        if not data.is_dir():
            print(f"shipped_model: error: {data}: not a folder; give folders of strips", file=sys.stderr)
            return 2
    models = [m for m in args.models.split(",") if m]
    env = dict(os.environ)
    text: list[str] = []
    for data in args.data:  # one folder: OUT/report-K as before; several: OUT/<folder>/report-K
        out = args.out if len(args.data) == 1 else args.out / data.name
        text += [*report_folder(data, models, out, args.judge_only, env), ""]
    report = "\n".join(text) + "\n"
    (args.out / "shipped.md").write_text(report)
    print("\n" + report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
