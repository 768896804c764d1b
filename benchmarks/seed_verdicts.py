#!/usr/bin/env python
"""What a verdict about one checkpoint is worth against the verdict about the method (issue 45).

Reads a finished ``svbrdf-bench run --seeds N --minutes ...`` from MLflow (its parent run id; the
store is ``MLFLOW_TRACKING_URI``'s) and prints, per training budget and pair of models, on the
render RMSE (and with ``--columns`` on other maps):

- the across-seed verdict the report states (seeds paired by seed, materials by material,
  hierarchical bootstrap: :func:`svbrdf_bench.report.seedstats.paired_seeds`);
- the single-fit verdicts a one-seed benchmark (the quick preset) would have given: every fit of
  A against every fit of B (N x N comparisons, each a paired bootstrap over materials alone), how
  many say "A beats B", "B beats A" or "within noise", and how many agree with the across-seed
  verdict;
- the between-seed spread of each model (standard deviation over seeds of each seed's mean render
  RMSE) beside the gap between the models' means.

Usage::

    MLFLOW_TRACKING_URI=sqlite:///fits/ablation-45/mlflow.db \\
        .venv/bin/python benchmarks/seed_verdicts.py PARENT_RUN_ID [--columns render,normal,diffuse]
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np


def _single(a: np.ndarray, b: np.ndarray) -> str:
    """One fit of A against one fit of B: paired over materials alone."""
    from svbrdf_bench.report.seedstats import paired_seeds

    d = paired_seeds({0: a}, {0: b})
    return "within noise" if d.within_noise else "A beats B" if d.high < 0 else "B beats A"


def _across(a: dict, b: dict) -> tuple[str, object]:
    from svbrdf_bench.report.seedstats import paired_seeds

    d = paired_seeds(a, b)
    return ("within noise" if d.within_noise else "A beats B" if d.high < 0 else "B beats A"), d


def rows(report, columns: list[str]) -> list[dict]:
    """One record per budget, pair of models and column (see the module doc)."""
    from svbrdf_bench.report.seedstats import cells

    found = cells(report)
    out = []
    for a, b in itertools.combinations(found, 2):
        if a.budget != b.budget or a.method == b.method:
            continue
        for column in columns:
            va, vb = a.values(report, f"rmse/{column}"), b.values(report, f"rmse/{column}")
            verdict, d = _across(va, vb)
            singles = [_single(va[i], vb[j]) for i in va for j in vb]
            means_a = [float(np.mean(v)) for v in va.values()]
            means_b = [float(np.mean(v)) for v in vb.values()]
            out.append({
                "budget": a.budget_text, "A": a.method, "B": b.method, "column": column,
                "A mean": np.mean(means_a), "B mean": np.mean(means_b),
                "A seed sd": float(np.std(means_a, ddof=1)) if len(means_a) > 1 else float("nan"),
                "B seed sd": float(np.std(means_b, ddof=1)) if len(means_b) > 1 else float("nan"),
                "difference": d.mean, "low": d.low, "high": d.high, "across seeds": verdict,
                "single fits": len(singles),
                "A beats B": singles.count("A beats B"), "B beats A": singles.count("B beats A"),
                "within noise": singles.count("within noise"), "agree": singles.count(verdict),
            })  # fmt: skip
    return out


def markdown(records: list[dict]) -> str:
    head = ("| budget | A | B | map | A mean (seed sd) | B mean (seed sd) | A - B [95%] | across seeds | "
            "single fits: A beats / B beats / within noise | agree |")  # fmt: skip
    lines = [head, "| --- | --- | --- | --- | ---: | ---: | ---: | --- | ---: | ---: |"]
    for r in records:
        lines.append(
            f"| {r['budget']} | {r['A']} | {r['B']} | {r['column']} | "
            f"{r['A mean']:.4f} ({r['A seed sd']:.4f}) | {r['B mean']:.4f} ({r['B seed sd']:.4f}) | "
            f"{r['difference']:+.4f} [{r['low']:+.4f}, {r['high']:+.4f}] | "
            f"{r['across seeds']} | {r['A beats B']} / {r['B beats A']} / {r['within noise']} | "
            f"{r['agree']} of {r['single fits']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("parent", help="the parent run id of a finished svbrdf-bench run with seeds")
    parser.add_argument("--columns", default="render", help="maps to compare, comma-separated (render)")
    args = parser.parse_args(argv)
    from svbrdf_bench.report import build_report

    report = build_report(args.parent)
    columns = [c.strip() for c in args.columns.split(",") if c.strip()]
    records = rows(report, columns)
    if not records:
        print(f"run {args.parent}: no two models share a budget; nothing to compare", file=sys.stderr)
        return 2
    print(markdown(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
