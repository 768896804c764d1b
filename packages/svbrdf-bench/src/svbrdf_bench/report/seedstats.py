"""The statistics of "Across seeds and budgets" (:mod:`svbrdf_bench.report.seeds` shows them):
what a model (a method, not one checkpoint) does at each training budget, from its rows of several
seeds (``--seeds N``) and budgets (``--minutes 2,8,32``, ``--steps``).

Per model and budget (a :class:`Cell`): each RMSE (renderings and each map) as the mean over
seeds of each seed's mean over materials (or test images), with a 95% interval from
:func:`hierarchical_bootstrap`, which resamples seeds, then materials. A verdict "A beats B at
budget X" holds only when that interval of the paired difference excludes 0
(:func:`paired_seeds`: seeds paired by seed, materials by material); each model's gain from one
budget to the next is judged the same way (the same fit at two budgets), and the front of render
RMSE against training minutes says which model and budget no cheaper one matches. The verdicts
in words (render: :func:`stated`) join the report's Holm family (:mod:`svbrdf_bench.report.verdicts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import BenchError
from ..layout import BUDGET_TAG, METHOD_TAG, SEED_TAG, budget_words, read_budget
from ..metrics import Difference
from .figures import Report
from .rows import COLUMNS, ModelEntry

__all__ = [
    "COLUMNS_RENDER_FIRST",
    "hierarchical_bootstrap",
    "paired_seeds",
    "tag_entry",
    "one_curve_per_fit",
    "Cell",
    "cells",
    "shown",
    "verdicts",
    "gains",
    "training_front",
    "cell_name",
    "stated",
]

#: The columns of the section, renderings first.
COLUMNS_RENDER_FIRST = ("render", *(c for c in COLUMNS if c != "render"))


# -- the statistics ---------------------------------------------------------------------------


def hierarchical_bootstrap(values, *, n_boot: int = 2000, level: float = 0.95, seed: int = 0):
    """``(mean, low, high)`` of a ``(seeds, units)`` array (units: materials or test images): the
    mean over seeds of each seed's mean over units, and its percentile interval from ``n_boot``
    resamples that draw seeds with replacement, then units with replacement.

    Every seed is scored on the same units (seeds and units are crossed, not nested), so one
    draw of units serves every seed drawn: a hard material stays hard for every seed, and more
    seeds do not shrink what the choice of materials leaves uncertain. One seed: the units alone
    are resampled; one unit: the seeds alone; one of each: the value itself.
    """
    x = _seeds_by_units(values, n_boot, level)
    low, high = np.quantile(_resampled(x, n_boot, seed), [(1 - level) / 2, (1 + level) / 2])
    return float(x.mean()), float(low), float(high)


def _seeds_by_units(values, n_boot: int, level: float) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 2 or x.size == 0:
        raise BenchError(f"hierarchical_bootstrap: expected a (seeds, units) array, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise BenchError(f"hierarchical_bootstrap: {int((~np.isfinite(x)).sum())} values are NaN or infinite")
    if n_boot < 1 or not 0 < level < 1:
        raise BenchError(f"hierarchical_bootstrap: n_boot >= 1 and level in (0, 1), got {n_boot}, {level}")
    return x


def _resampled(x: np.ndarray, n_boot: int, seed: int) -> np.ndarray:
    """The statistic of :func:`hierarchical_bootstrap` over ``n_boot`` resamples (as counts: a
    seed or unit drawn k times weighs k)."""
    s, u = x.shape
    rng = np.random.default_rng(seed)
    rows = np.arange(n_boot)[:, None]
    seed_weights = np.zeros((n_boot, s))
    np.add.at(seed_weights, (rows, rng.integers(0, s, (n_boot, s))), 1.0)
    unit_weights = np.zeros((n_boot, u))
    np.add.at(unit_weights, (rows, rng.integers(0, u, (n_boot, u))), 1.0)
    per_seed = unit_weights @ x.T / u  # (n_boot, seeds): each seed's mean over the units drawn
    return (seed_weights * per_seed).sum(axis=1) / s


def paired_seeds(
    a: dict[int, np.ndarray], b: dict[int, np.ndarray], *, n_boot: int = 2000, level: float = 0.95,
    seed: int = 0,
) -> Difference | None:  # fmt: skip
    """``mean(a - b)`` over the seeds both have (``{seed: values per unit}``), seeds paired by
    seed (the same data and sampling seed) and units by unit, with its
    :func:`hierarchical_bootstrap` interval and two-sided p-value
    (:func:`svbrdf_bench.metrics.bootstrap_p_value`); None when they share no seed."""
    from ..metrics import bootstrap_p_value

    common = sorted(set(a) & set(b))
    if not common:
        return None
    d = _seeds_by_units([np.asarray(a[s], np.float64) - np.asarray(b[s], np.float64) for s in common],
                        n_boot, level)  # fmt: skip
    stats = _resampled(d, n_boot, seed)
    low, high = (float(q) for q in np.quantile(stats, [(1 - level) / 2, (1 + level) / 2]))
    p = bootstrap_p_value(stats if d.size > 1 else None)
    return Difference(float(d.mean()), low, high, bool(low <= 0 <= high), p)


# -- the rows, read back ------------------------------------------------------------------------


def tag_entry(entry: ModelEntry | None, tags: dict[str, str]) -> ModelEntry | None:
    """``entry`` with its seed, model and budget from its child run's tags (:mod:`svbrdf_bench.layout`)."""
    if entry is not None and SEED_TAG in tags:
        entry.seed = int(tags[SEED_TAG])
        entry.method = tags.get(METHOD_TAG) or entry.label
        entry.train_budget = read_budget(tags.get(BUDGET_TAG))
    return entry


def one_curve_per_fit(models: list[ModelEntry]) -> list[ModelEntry]:
    """The learning curve of a fit scored at several budgets, on its last budget's row alone (the
    rows of one fit would draw the same line once per budget)."""
    last: dict[str, ModelEntry] = {}
    for e in models:
        if e.train_budget is not None and not e.refine_steps and not e.baseline:
            if e.train_run_id not in last or e.train_budget[1] > last[e.train_run_id].train_budget[1]:
                last[e.train_run_id] = e
    for e in models:
        if e.train_budget is not None and e.train_run_id in last and last[e.train_run_id] is not e:
            e.curve, e.curve_real = ([], []), ([], [])
    return models


# -- per model and budget -----------------------------------------------------------------------


@dataclass
class Cell:
    """One model at one training budget: its rows by seed."""

    method: str
    budget: tuple[str, float] | None
    rows: dict[int, ModelEntry] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """``ours @ 8 min``; ``ours`` when the budget is the recipe's or the reused fit's own."""
        return self.method if self.budget is None else f"{self.method} @ {budget_words(*self.budget)}"

    @property
    def budget_text(self) -> str:
        return "-" if self.budget is None else budget_words(*self.budget)

    def values(self, report: Report, key: str) -> dict[int, np.ndarray]:
        """``{seed: the figure per material (or test image)}``."""
        return {s: report.values(e, key) for s, e in sorted(self.rows.items())}

    def matrix(self, report: Report, key: str) -> np.ndarray:
        """The figure as a ``(seeds, units)`` array."""
        values = list(self.values(report, key).values())
        if len({len(v) for v in values}) != 1:
            raise BenchError(f"{self.name}: its seeds were tested on different test sets")
        return np.stack(values)

    def cost_minutes(self) -> float:
        """The training cost the front compares: the budget mark for a budget in minutes (each fit
        was given exactly that; its snapshot lands at the first step past the mark, so the measured
        minutes of two models at one mark differ by a step, which is no difference in cost), else
        :meth:`minutes`."""
        if self.budget is not None and self.budget[0] == "minutes":
            return float(self.budget[1])
        return self.minutes()

    def minutes(self) -> float:
        """Mean training minutes over its seeds (on the fits' clock); NaN when not recorded."""
        t = [e.figures.get("time/train_s", math.nan) for e in self.rows.values()]
        t = [v for v in t if not math.isnan(v)]
        return float(np.mean(t)) / 60 if t else math.nan


def cells(report: Report) -> list[Cell]:
    """The competitors' rows by model and budget, models in the order they appear, budgets rising."""
    out: dict[tuple, Cell] = {}
    for e in report.competitors:
        method = e.method or e.label
        key = (method, e.train_budget)
        cell = out.setdefault(key, Cell(method, e.train_budget))
        cell.rows[e.seed if e.seed is not None else len(cell.rows)] = e
    order = list(dict.fromkeys(c.method for c in out.values()))
    return sorted(out.values(), key=lambda c: (order.index(c.method), c.budget or ("", -1.0)))


def shown(report: Report) -> bool:
    """Whether the section has something to show: a model of several seeds or several budgets."""
    found = cells(report)
    methods = [c.method for c in found]
    return any(len(c.rows) > 1 for c in found) or len(methods) != len(set(methods))


# -- the comparisons --------------------------------------------------------------------------


def _verdict(d: Difference) -> str:
    return "within noise" if d.within_noise else "beats" if d.high < 0 else "worse"


def _record(a: Cell, b: Cell, column: str, d: Difference, seeds: int) -> dict:
    """One comparison at one budget, oriented so that ``model`` has the lower mean RMSE."""
    if d.mean > 0:
        a, b, d = b, a, Difference(-d.mean, -d.high, -d.low, d.within_noise, d.p_value)
    return {"budget": a.budget_text, "model": a.method, "versus": b.method, "column": column,
            "rmse_difference": d.mean, "low": d.low, "high": d.high, "seeds": seeds,
            "verdict": _verdict(d), "p_value": d.p_value}  # fmt: skip


def _pairs(report: Report, pairs: list[tuple[Cell, Cell]], columns=COLUMNS_RENDER_FIRST) -> list[dict]:
    out = []
    for a, b in pairs:
        for c in columns:
            va, vb = a.values(report, f"rmse/{c}"), b.values(report, f"rmse/{c}")
            if any(v is None for v in (*va.values(), *vb.values())):
                continue
            d = paired_seeds(va, vb)
            if d is not None:
                out.append(_record(a, b, c, d, len(set(va) & set(vb))))
    return out


def verdicts(report: Report, columns=COLUMNS_RENDER_FIRST) -> list[dict]:
    """Every pair of models at each budget they share, per column: the better one's RMSE minus the
    other's, paired by seed and material, with its :func:`hierarchical_bootstrap` interval;
    ``beats`` only when the interval lies below 0."""
    found = cells(report)
    pairs = [(a, b) for i, a in enumerate(found) for b in found[i + 1 :]
             if a.budget == b.budget and a.method != b.method]  # fmt: skip
    return _pairs(report, pairs, columns)


def gains(report: Report) -> list[dict]:
    """Each model from one budget to the next (render RMSE): the same fits at two budgets, paired by
    seed and material; ``beats``: the larger budget is better beyond noise."""
    found = [c for c in cells(report) if c.budget is not None]
    pairs = [(b, a) for a, b in zip(found, found[1:], strict=False)
             if a.method == b.method and a.budget[0] == b.budget[0]]  # fmt: skip
    out = []
    for later, earlier in pairs:
        d = paired_seeds(later.values(report, "rmse/render"), earlier.values(report, "rmse/render"))
        if d is not None:
            out.append({"model": later.method, "from": earlier.budget_text, "to": later.budget_text,
                        "rmse_difference": d.mean, "low": d.low, "high": d.high,
                        "verdict": _verdict(d), "p_value": d.p_value})  # fmt: skip
    return out


def cell_name(method: str, budget: str) -> str:
    """``ours @ 8 min`` (``ours`` where the budget is ``-``): a model at a budget in the Holm family."""
    return method if budget == "-" else f"{method} @ {budget}"


def stated(report: Report) -> list[dict]:
    """The verdicts the section states in words, for the report's Holm family: each pair of models
    at each budget on render RMSE (``across seeds``) and each model's gain from one budget to the
    next (``budget gain``); ``model`` and ``versus`` as :func:`cell_name` writes them. Empty when the
    section is absent."""
    if not shown(report):
        return []
    out = [{"kind": "across seeds", "model": cell_name(r["model"], r["budget"]),
            "versus": cell_name(r["versus"], r["budget"]), **_figures(r)}
           for r in verdicts(report, ("render",))]  # fmt: skip
    out += [{"kind": "budget gain", "model": cell_name(r["model"], r["to"]),
             "versus": cell_name(r["model"], r["from"]), **_figures(r)} for r in gains(report)]  # fmt: skip
    return out


def _figures(r: dict) -> dict:
    return {k: r[k] for k in ("rmse_difference", "low", "high", "verdict", "p_value")}


def training_front(report: Report) -> dict:
    """The front of render RMSE against training minutes over every model and budget: a point is
    dominated when one trained no longer is better, or within noise of it (:func:`paired_seeds`),
    as :func:`svbrdf_bench.plots.dominated_by` decides. Training time is :meth:`Cell.cost_minutes`:
    models at one budget in minutes cost the same, and neither dominates the other unless it is
    better beyond noise."""
    from ..plots import dominated_by

    points, by_name = {}, {}
    for c in cells(report):
        minutes = c.cost_minutes()
        if not math.isnan(minutes):
            points[c.name] = (minutes, *hierarchical_bootstrap(c.matrix(report, "rmse/render")))
            by_name[c.name] = c
    if len(points) < 2:
        return {"points": points, "front": list(points), "dominated": {}}
    names = list(points)
    render = {n: c.values(report, "rmse/render") for n, c in by_name.items()}
    ties = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]
            if (d := paired_seeds(render[a], render[b])) is not None and d.within_noise]  # fmt: skip
    by = dominated_by(points, within_noise=ties)
    front = sorted((n for n in names if by[n] is None), key=lambda n: points[n][0])
    return {"points": points, "front": front, "dominated": {n: b for n, b in by.items() if b is not None}}
