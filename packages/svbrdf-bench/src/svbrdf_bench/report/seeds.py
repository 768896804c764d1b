"""The report's section "Across seeds and budgets": per model and budget, each RMSE over seeds
with the between-seed standard deviation and its interval, then the verdicts, gains, spreads and
training-time front in words (the statistics: :mod:`svbrdf_bench.report.seedstats`), read back
from MLflow like every other table. A verdict Holm overturns over the report's family
(:mod:`svbrdf_bench.report.verdicts`) says so.

With one seed and one budget per model the section is absent (:func:`~.seedstats.shown`).
"""

from __future__ import annotations

import math

import numpy as np

from .figures import Report
from .seedstats import (
    COLUMNS_RENDER_FIRST,
    Cell,
    cell_name,
    cells,
    gains,
    hierarchical_bootstrap,
    shown,
    training_front,
    verdicts,
)
from .tables import Table
from .verdicts import family

__all__ = ["SECTION", "seeds_table", "section_lines", "section_json", "training_time_series"]

SECTION = "Across seeds and budgets"
_COLUMNS = COLUMNS_RENDER_FIRST


# -- how the section shows them -----------------------------------------------------------------


def _matrix_or_none(report: Report, cell: Cell, key: str) -> np.ndarray | None:
    values = cell.values(report, key)
    return None if any(v is None for v in values.values()) else cell.matrix(report, key)


def _cell_text(m: np.ndarray) -> str:
    """``0.1234 ±0.0012 [0.1200, 0.1300]``: mean over seeds, between-seed std, 95% interval."""
    mean, low, high = hierarchical_bootstrap(m)
    spread = f" ±{np.std(m.mean(axis=1), ddof=1):.4f}" if m.shape[0] > 1 else ""
    return f"{mean:.4f}{spread} [{low:.4f}, {high:.4f}]"


def seeds_table(report: Report) -> Table | None:
    """The section: per model and budget, each RMSE over seeds, then the verdicts in words
    (:func:`section_lines`); None when there is one seed and one budget per model."""
    if not shown(report):
        return None
    rows = []
    for c in cells(report):
        minutes = c.minutes()
        row = [c.method, c.budget_text, ",".join(map(str, c.rows))]
        row.append("-" if math.isnan(minutes) else f"{minutes:.2f}")
        for col in _COLUMNS:
            m = _matrix_or_none(report, c, f"rmse/{col}")
            row.append("-" if m is None else _cell_text(m))
        rows.append(row)
    title = (f"{SECTION} (RMSE, lower is better: mean over seeds of each seed's mean over "
             f"{report.unit}, ±the between-seed standard deviation, [95% interval])")  # fmt: skip
    head = ["model", "budget", "seeds", "train min", *(f"{c} RMSE" for c in _COLUMNS)]
    return Table(title, head, rows, ["", *section_lines(report)])


def _difference(r: dict) -> str:
    return f"{r['rmse_difference']:+.4f} [{r['low']:+.4f}, {r['high']:+.4f}]"


def _verdict_lines(report: Report) -> list[str]:
    """Render RMSE: each pair of models at each budget, then each model's gain budget to budget; a
    verdict that Holm overturns over the report's family says so."""
    fam = family(report)

    def holm(model: str, versus: str) -> str:
        v = fam.get(model, versus, "render")
        return "" if v is None or v.survives else f", but not after Holm over {fam.count} comparisons"

    lines = []
    for r in verdicts(report, ("render",)):
        at = f"At {r['budget']}: " if r["budget"] != "-" else ""
        n = f"{r['seeds']} seed{'s' if r['seeds'] > 1 else ''}"
        if r["verdict"] == "beats":
            after = holm(cell_name(r["model"], r["budget"]), cell_name(r["versus"], r["budget"]))
            lines.append(f"{at}{r['model']} beats {r['versus']} on render RMSE by {_difference(r)} "
                         f"({n}){after}.")  # fmt: skip
        else:
            lines.append(f"{at}{r['model']} and {r['versus']} are within noise on render RMSE: "
                         f"{_difference(r)} ({n}).")  # fmt: skip
    stopped = set()
    for r in gains(report):
        said = {"beats": "gains", "worse": "loses beyond noise", "within noise": "no gain beyond noise"}
        line = f"{r['model']} from {r['from']} to {r['to']}: {_difference(r)}, {said[r['verdict']]}"
        if r["verdict"] != "within noise":
            line += holm(cell_name(r["model"], r["to"]), cell_name(r["model"], r["from"]))
        if r["verdict"] != "beats" and r["model"] not in stopped:
            stopped.add(r["model"])
            line += f": it stops gaining after {r['from']}"
        lines.append(line + ".")
    return lines


def _spread_lines(report: Report) -> list[str]:
    """Per budget, the largest between-seed spread of render RMSE against the gap between models."""
    by_budget: dict = {}
    for c in cells(report):
        if len(c.rows) > 1:
            by_budget.setdefault(c.budget_text, []).append(c)
    lines = []
    for budget, group in by_budget.items():
        sds = {c.method: float(np.std(c.matrix(report, "rmse/render").mean(axis=1), ddof=1)) for c in group}
        means = {c.method: float(c.matrix(report, "rmse/render").mean()) for c in group}
        worst = max(sds, key=sds.get)
        spread = max(means.values()) - min(means.values())
        gap = f"; gap between models {spread:.4f}" if len(means) > 1 else ""
        at = f"at {budget}" if budget != "-" else "across seeds"
        lines.append(f"Render RMSE {at}: between-seed std up to {sds[worst]:.4f} ({worst}){gap}.")
    return lines


def section_lines(report: Report) -> list[str]:
    """The section in words: how the figures were made, budgets not reached, the verdicts, each
    model's gains, the spread against the gaps, and the front of render RMSE against training time."""
    found = cells(report)
    lines = [f"Intervals: 2000 resamples drawing seeds, then {report.unit} (one draw of {report.unit} "
             "shared by the seeds drawn: every seed is tested on the same ones); a verdict holds only "
             "when the interval of the paired difference (seed with seed, "
             f"{report.unit[:-1]} with {report.unit[:-1]}) excludes 0."]  # fmt: skip
    if max(len(c.rows) for c in found) == 1:
        lines.append("One seed per model: these verdicts compare checkpoints, not methods (--seeds 3 trains "
                     "three fits per model and judges across them).")  # fmt: skip
    lines += [f"Not reached: {m['model']} seed {m['seed']} @ {m['budget']}: {m['why']}."
              for m in report.missed_budgets]
    lines += _verdict_lines(report) + _spread_lines(report)
    front = training_front(report)
    if len(front["points"]) > 1:
        why = [f"{n} (by {b})" for n, b in front["dominated"].items()]
        lines.append("Render RMSE against training minutes: on the front (trained no longer than, and "
                     f"better beyond noise than, every other): {', '.join(front['front'])}"
                     + (f"; dominated: {', '.join(why)}" if why else "") + ".")  # fmt: skip
    return lines


def section_json(report: Report) -> dict | None:
    """The section for results.json: per model and budget its figures over seeds, the verdicts (every
    column), the gains, the training-time front and the budgets not reached; None when absent."""
    if not shown(report):
        return None
    out = []
    for c in cells(report):
        figures = {}
        for col in _COLUMNS:
            m = _matrix_or_none(report, c, f"rmse/{col}")
            if m is not None:
                mean, low, high = hierarchical_bootstrap(m)
                per_seed = m.mean(axis=1)
                std = float(np.std(per_seed, ddof=1)) if len(per_seed) > 1 else 0.0
                figures[col] = {"mean": mean, "low": low, "high": high, "seed_std": std,
                                "seed_min": float(per_seed.min()),
                                "seed_max": float(per_seed.max())}  # fmt: skip
        out.append({"model": c.method, "budget": c.budget_text, "seeds": list(c.rows),
                    "train_minutes": c.minutes(), "rmse": figures})  # fmt: skip
    front = training_front(report)
    return {"cells": out, "verdicts": verdicts(report), "gains": gains(report),
            "training_front": {"front": front["front"], "dominated": front["dominated"]},
            "missed": list(report.missed_budgets)}  # fmt: skip


def training_time_series(report: Report) -> dict[str, list[tuple]]:
    """``{model: [(training minutes, budget, (render RMSE mean, low, high))]}`` for
    :func:`svbrdf_bench.plots.accuracy_vs_training_time`; empty when the section is absent."""
    if not shown(report):
        return {}
    series: dict[str, list] = {}
    for c in cells(report):
        minutes = c.minutes()
        m = _matrix_or_none(report, c, "rmse/render")
        if not math.isnan(minutes) and minutes > 0 and m is not None:
            series.setdefault(c.method, []).append((minutes, c.budget_text, hierarchical_bootstrap(m)))
    return series
