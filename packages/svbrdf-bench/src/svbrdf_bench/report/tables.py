"""The report's tables as data: :class:`Table` (a title, a header, rows of cells as text, and the
lines that follow it), one builder per table, each from a
:class:`~svbrdf_bench.report.figures.Report`. How a table looks (aligned columns in the terminal,
a pipe table in Markdown) is :mod:`svbrdf_bench.report.text`'s business.

A builder returns None when its table has nothing to show (no baseline, no real photos, no
refined rows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..layout import INPUT_RERENDER, REAL_RERENDER, SECONDS_PER_IMAGE
from .figures import Report
from .rows import COLUMNS, PURE_OPTIMISATION, REFERENCE, SPREADS, TIME_COLUMNS
from .verdicts import ALPHA, Family, family
from .words import REAL_CAVEAT, REAL_REFINED_CAVEAT, cost_notes, ratio

__all__ = [
    "Table",
    "accuracy_table",
    "against_table",
    "real_table",
    "refine_table",
    "time_table",
    "phase_table",
    "cost_table",
    "verdict_table",
]


@dataclass
class Table:
    """One table of the report, its cells already written as text."""

    title: str
    head: list[str]
    #: One list of cells per row, as shown.
    rows: list[list[str]]
    #: Lines shown after the table, as they are (notes, caveats).
    after: list[str] = field(default_factory=list)


def _interval(ci: tuple[float, float, float] | None) -> str:
    return "-" if ci is None else f"{ci[0]:.4f} [{ci[1]:.4f}, {ci[2]:.4f}]"


def accuracy_table(report: Report, metric: str, title: str, sense: str) -> Table:
    """One metric (``rmse``, ``ssim``, ``lpips``) per row and column, with its 95% interval."""
    rows = [[e.name, *(_interval(report.interval(e, metric, c)) for c in COLUMNS)] for e in report.models]
    over = (
        "mean over materials; 95% bootstrap interval over materials"
        if report.per_material_on
        else "95% bootstrap interval over test images"
    )
    return Table(f"{title} ({sense}; {over})", ["model", *COLUMNS], rows)


def against_table(report: Report, fam: Family | None = None) -> Table | None:
    """Each trained row's RMSE minus ``mean``'s, per column, with its interval and verdict (marked
    where it does not survive Holm over the report's ``fam``ily of verdicts)."""
    fam = family(report) if fam is None else fam
    rows_by_model: dict[str, dict[str, str]] = {}
    for r in report.against_reference():
        rel = "" if math.isnan(r["relative"]) else f" ({100 * r['relative']:+.0f}%)"
        v = fam.get(r["model"], r["versus"], r["column"])
        verdict = r["verdict"] if v is None else fam.words(v)
        cell = f"{r['rmse_difference']:+.4f}{rel} [{r['low']:+.4f}, {r['high']:+.4f}] {verdict}"
        rows_by_model.setdefault(r["model"], {})[r["column"]] = cell
    if not rows_by_model:
        return None
    rows = [[m, *(cells.get(c, "-") for c in COLUMNS)] for m, cells in rows_by_model.items()]
    refined = (
        f"; a row refined for N steps against `{REFERENCE} +refine N`, the {PURE_OPTIMISATION}"
        if any(e.refine_steps for e in report.trained)
        else ""
    )
    title = (
        f"Against the {REFERENCE} baseline (RMSE of the model minus RMSE of `{REFERENCE}` on the same "
        f"{'materials' if report.per_material_on else 'images'}, in % of `{REFERENCE}`'s RMSE, 95% paired "
        "bootstrap interval; beats: the whole "
        f"interval below 0{refined})"
    )
    return Table(title, ["model", *COLUMNS], rows)


def time_table(report: Report) -> Table:
    """Time and memory per row: medians with their IQR where logged, ``-`` where not measured."""
    cols = [c for c in TIME_COLUMNS if any(c[0] in e.figures for e in report.models)]
    rows = []
    for e in report.models:
        cells = [e.short]
        for key, _, fmt in cols:
            v = e.figures.get(key, math.nan)
            if key == "model/params":
                v = v / 1e6
            median, iqr = (e.figures.get(k, math.nan) for k in SPREADS.get(key, (key, "")))
            if not (math.isnan(median) or math.isnan(iqr)):  # median [IQR]
                cells.append(f"{fmt.format(median)} [{fmt.format(iqr)}]")
                continue
            cells.append("-" if v is None or math.isnan(v) else fmt.format(v))
        rows.append(cells)
    after = []
    if report.reference_rows:
        after = [
            "",
            "Rows marked (reference): training time and steps as their model files record them, "
            "on their own budget and hardware; not this benchmark's budget, and not comparable "
            "with it.",
        ]
    return Table("Time and memory", ["model", *(c[1] for c in cols)], rows, after)


def phase_table(report: Report) -> Table | None:
    """Where the benchmark's wall time went, phase by phase (None for runs that did not record it)."""
    if not report.phases:
        return None
    total = sum(s for _, s in report.phases)
    rows = [[name, f"{s:.1f}", f"{s / total:.0%}" if total > 0 else "-"] for name, s in report.phases]
    rows.append(["total (before the report)", f"{total:.1f}", "100%" if total > 0 else "-"])
    return Table("Where the time went", ["phase", "wall s", "share"], rows)


def refine_table(report: Report) -> Table | None:
    """Accuracy against capture time: every row with refinement on, at every budget."""
    if not report.refined:
        return None
    rows = []
    for e in report.models:
        seconds = e.figures.get(SECONDS_PER_IMAGE, math.nan)
        cells = [e.name, str(e.refine_steps), "-" if math.isnan(seconds) else f"{seconds:.3g}"]
        for key in (INPUT_RERENDER, "rmse/render", "rmse/diffuse"):
            cells.append(_interval(report.interval(e, *key.split("/", 1))))
        rows.append(cells)
    head = ["model", "refine steps", "s/image (net + refine)", "photo re-render RMSE", "render RMSE",
            "diffuse RMSE"]  # fmt: skip
    title = (
        "Refinement: accuracy against capture time (photo re-render: the maps under the refinement's "
        "flash against the test photo, what refinement optimises; render: the 6 evaluation views "
        "against the true maps'; 95% bootstrap intervals)"
    )
    return Table(title, head, rows)


def real_table(report: Report) -> Table | None:
    """Real photos have no ground truth: the re-rendering under the fitted flash is the figure."""
    from ..metrics import bootstrap_ci

    rows = []
    for e in report.models:
        values = e.per_sample.get(REAL_RERENDER)
        if values is None or len(values) == 0:
            continue
        mean, low, high = bootstrap_ci(values)
        rows.append(
            [e.name, str(len(values)), f"{np.median(values):.4f}", f"{mean:.4f} [{low:.4f}, {high:.4f}]"]
        )
    if not rows:
        return None
    head = ["model", "photos", "median re-render RMSE", "mean [95%]"]
    refined = any(e.refine_steps and len(e.per_sample.get(REAL_RERENDER, ())) for e in report.models)
    after = ["", REAL_CAVEAT, *(["", REAL_REFINED_CAVEAT] if refined else [])]
    title = f"Real photos ({report.real_data}): maps re-rendered under the fitted flash"
    return Table(title, head, rows, after)


def cost_table(report: Report, fam: Family | None = None) -> Table:
    """What each pair of trained rows' accuracy costs (:meth:`Report.costs`), the pairs in words after."""
    costs = report.costs()
    fam = family(report) if fam is None else fam
    short = {e.label: e.short for e in report.costed}

    def noise(c: dict) -> str:
        v = fam.get(c["model"], c["versus"], "render")
        return fam.words(v) if v is not None else "within noise" if c["within_noise"] else "beyond noise"

    rows = [
        [
            f"{short[c['model']]} vs {short[c['versus']]}",
            f"{c['render_rmse_difference']:+.4f} [{c['low']:+.4f}, {c['high']:+.4f}]",
            noise(c),
            ratio(c["train_time_per_step_ratio"]),
            ratio(c["latency_ratio"]),
            ratio(c["params_ratio"]),
        ]
        for c in costs
    ]
    head = ["pair", "render RMSE difference [95%]", "noise", "train time/step", "latency", "params"]
    title = "What accuracy costs (trained models" + (
        "; reference rows: not equal-budget)" if any(c["reference"] for c in costs) else ")"
    )
    return Table(title, head, rows, cost_notes(report, costs))


def verdict_table(report: Report, fam: Family | None = None) -> Table | None:
    """Every verdict of the report (:func:`~svbrdf_bench.report.verdicts.family`): the difference
    per material (or image) with its 95% interval, its p-value and Holm-adjusted p, the verdict
    after Holm; on a test set of few materials, the per-strip interval and verdict beside."""
    fam = family(report) if fam is None else fam
    if not fam.count:
        return None
    strips = any(v.strips is not None for v in fam.verdicts)
    unit = "material" if report.per_material_on else "image"
    head = ["comparison", "column", f"difference per {unit} [95%]", "p", "Holm p", "verdict"]
    head += ["per strip [95%]", "per strip"] if strips else []
    rows = []
    for v in fam.verdicts:
        cells = [fam.pair(v), v.column, f"{v.difference:+.4f} [{v.low:+.4f}, {v.high:+.4f}]",
                 f"{v.p_value:.4f}", f"{v.holm_p:.4f}", fam.words(v)]  # fmt: skip
        if strips:
            d = v.strips
            cells += ["-", "-"] if d is None else [f"{d.mean:+.4f} [{d.low:+.4f}, {d.high:+.4f}]",
                                                   d.verdict()]  # fmt: skip
        rows.append(cells)
    title = (
        f"Verdicts: {fam.count} comparisons, corrected together by Holm at {ALPHA:.0%} (RMSE of the model "
        "minus the other's, paired bootstrap; p: two-sided, twice the share of resamples on the far side "
        "of 0, 0.0000 when none is; Holm p: adjusted for the number of comparisons)"
    )
    return Table(title, head, rows)
