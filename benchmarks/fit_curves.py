#!/usr/bin/env python
"""Validation curves of fits recorded in an MLflow store, as a table and a figure.

For each run (by id, or every run of ``--experiment``), the validation metrics of the chosen
prefixes (``val_fold/``: the held-out real-train fold; ``val_real/``: a watched real set such as
unseen-dev; ``val/``) at every validated step, then a figure with one panel per map and prefix.
The last column of the table is the mean over the validations from ``--from-step`` on, less
noisy than one validation of a GAN.

Usage::

    MLFLOW_TRACKING_URI=sqlite:///fits/ours-materials/mlflow.db \\
        .venv/bin/python benchmarks/fit_curves.py --experiment shipped -o docs/curves.png
    .venv/bin/python benchmarks/fit_curves.py RUN_ID RUN_ID --prefix val_fold --from-step 1000
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

METRICS = ("normal", "diffuse", "roughness", "specular", "render")


def _runs(client, ids: list[str], experiment: str | None) -> list:
    if ids:
        return [client.get_run(i) for i in ids]
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        raise SystemExit(f"no experiment {experiment!r} in {client.tracking_uri}")
    return list(reversed(client.search_runs([exp.experiment_id])))


def _label(run) -> str:
    """The run's name and id, and the share of real strips of its mix when it has one."""
    import ast

    label = f"{run.info.run_name} {run.info.run_id[:8]}"
    try:
        mix = ast.literal_eval(run.data.params.get("data.mix", "None")) or []
    except (ValueError, SyntaxError):
        return label
    total = sum(float(e.get("weight", 0)) for e in mix)
    real = sum(float(e.get("weight", 0)) for e in mix if e.get("source") == "materials")
    return f"{label}, {real / total:.0%} real strips" if total and real else label


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", help="run ids (default: every run of --experiment)")
    ap.add_argument("--experiment", default=None, help="experiment name")
    ap.add_argument("--prefix", action="append", help="metric prefixes (default val_fold and val_real)")
    ap.add_argument("--from-step", type=int, default=0, help="first step of the mean column")
    ap.add_argument("-o", "--out", type=Path, help="figure (.png)")
    args = ap.parse_args(argv)
    if not args.runs and not args.experiment:
        ap.error("give run ids or --experiment NAME")
    from mlflow import MlflowClient

    client = MlflowClient()
    prefixes = args.prefix or ["val_fold", "val_real"]
    curves: dict[tuple[str, str, str], list[tuple[int, float]]] = {}
    for run in _runs(client, args.runs, args.experiment):
        for prefix in prefixes:
            for m in METRICS:
                history = client.get_metric_history(run.info.run_id, f"{prefix}/rmse/{m}")
                if history:
                    curves[(_label(run), prefix, m)] = sorted((h.step, h.value) for h in history)
    if not curves:
        raise SystemExit("no validation metrics of those prefixes in those runs")
    for (label, prefix, m), points in curves.items():
        late = [v for s, v in points if s >= args.from_step] or [points[-1][1]]
        shown = " ".join(f"{s}:{v:.4f}" for s, v in points)
        print(
            f"{label} | {prefix}/{m} | {shown} | mean from step {args.from_step}: {statistics.mean(late):.4f}"
        )
    if args.out:
        _plot(curves, prefixes, args.out)


def _plot(curves, prefixes, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(prefixes), len(METRICS), figsize=(3.2 * len(METRICS), 2.6 * len(prefixes)), squeeze=False, dpi=100
    )
    labels = list(dict.fromkeys(k[0] for k in curves))
    for r, prefix in enumerate(prefixes):
        for c, m in enumerate(METRICS):
            ax = axes[r][c]
            for label in labels:
                points = curves.get((label, prefix, m))
                if points:
                    ax.plot(*zip(*points, strict=True), marker=".", label=label)
            ax.set_title(f"{prefix} {m}", fontsize=9)
            ax.set_xlabel("step", fontsize=8)
            ax.tick_params(labelsize=7)
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=min(3, len(names)), fontsize=8)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
