"""How far a report's verdicts can be trusted: how many it makes, which survive a Holm correction
for that number, and, on a test set of few materials, what its intervals are worth.

A verdict is a paired comparison with a 95% bootstrap interval: each trained row against
``mean`` (a refined row against the pure-optimisation baseline), map by map and on renderings
(:meth:`Report.against_reference`), and each pair of "what accuracy costs" on renderings
(:meth:`Report.costs`), and with several seeds or budgets the verdicts of "Across seeds and
budgets" (:func:`svbrdf_bench.report.seedstats.stated`). They form the report's family
(:func:`family`). At 95%, one verdict in
20 is "beyond noise" by chance where there is no difference, so over N verdicts some are
expected by chance alone. Each comparison's p-value is its own bootstrap's, two-sided: twice
the share of the resampled differences on the far side of zero
(:func:`svbrdf_bench.metrics.bootstrap_p_value`); Holm's step-down procedure
(:func:`svbrdf_bench.metrics.holm`) at the report's level, 5%, keeps the chance of any false
verdict in the family at 5%. A verdict that does not survive it reads "beats, but not after
Holm over N comparisons"; "within noise" has nothing to survive.

With fewer than :data:`SMALL_SAMPLE` materials (des18-dev has 4), a bootstrap over materials
is unreliable: 4 materials have 35 distinct resamples, and when every material moves the same
way the interval collapses onto the mean ("+2% [+2, +2]") and the p-value to 0, where an exact
sign test on 4 materials cannot go below 0.125. The report then says so
(:func:`small_sample_note`) and sets each comparison's per-strip interval (the same paired
bootstrap over strips: more units, but not independent ones, for strips share materials) beside
the per-material one; a verdict that holds on both is the firmer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..metrics import Difference
from .figures import Report
from .seedstats import stated

__all__ = ["ALPHA", "SMALL_SAMPLE", "Verdict", "Family", "family", "unit_count", "small_sample_note",
           "holm_note", "holm_clause"]  # fmt: skip

#: The report's level: its intervals are 95%, Holm keeps the family-wise error at 5%.
ALPHA = 0.05
#: Fewer material groups (images, on an ungrouped test set) than this: the report says its
#: intervals are unreliable, and shows per-strip intervals beside the per-material ones.
SMALL_SAMPLE = 8
#: The verdict of a between-model pair ("what accuracy costs") beyond noise.
BETTER = "beyond noise"


@dataclass(frozen=True)
class Verdict:
    """One comparison of the report: ``model`` minus ``versus`` on ``column`` (RMSE), per material
    (or per image), with its 95% interval, p-value, Holm-adjusted p, and per-strip interval."""

    #: ``against baseline`` (a row against ``mean`` or the pure-optimisation baseline) or
    #: ``between models`` (a pair of "what accuracy costs"), ``across seeds`` (two models at one
    #: budget over their seeds) or ``budget gain`` (a model from one budget to the next).
    kind: str
    model: str
    versus: str
    column: str
    difference: float
    low: float
    high: float
    #: As the 95% interval says: ``beats``, ``worse``, ``within noise`` (between models:
    #: ``beyond noise`` or ``within noise``).
    verdict: str
    p_value: float
    #: Holm-adjusted p over the report's family (:func:`svbrdf_bench.metrics.holm_adjusted`).
    holm_p: float
    #: The same paired bootstrap over strips, on a grouped test set of few materials; else None.
    strips: Difference | None = None

    @property
    def decided(self) -> bool:
        """The interval excludes 0: a verdict that Holm may overturn."""
        return self.verdict != "within noise"

    @property
    def survives(self) -> bool:
        """A decided verdict whose Holm-adjusted p is within :data:`ALPHA` (undecided: True)."""
        return not self.decided or self.holm_p <= ALPHA


@dataclass(frozen=True)
class Family:
    """Every verdict of a report, Holm-corrected together."""

    verdicts: list[Verdict]
    #: Row label -> the short name the report gives it where rows are paired (``NAME (reference)``).
    names: dict[str, str] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.verdicts)

    def get(self, model: str, versus: str, column: str) -> Verdict | None:
        key = (model, versus, column)
        return next((v for v in self.verdicts if (v.model, v.versus, v.column) == key), None)

    def pair(self, v: Verdict) -> str:
        """``A vs B`` in the rows' short names."""
        return f"{self.names.get(v.model, v.model)} vs {self.names.get(v.versus, v.versus)}"

    def words(self, v: Verdict) -> str:
        """The verdict as the tables print it: ``beats``, or ``beats, but not after Holm over 14
        comparisons`` where it does not survive the correction."""
        return v.verdict if v.survives else f"{v.verdict}, but not after Holm over {self.count} comparisons"

    def overturned(self, model: str | None = None) -> list[Verdict]:
        """The decided verdicts (of ``model``'s rows, if given) that do not survive Holm."""
        return [v for v in self.verdicts if not v.survives and model in (None, v.model)]


def unit_count(report: Report) -> tuple[int, int]:
    """``(units, strips)``: the materials (an ungrouped test set: the test images) the per-material
    figures average over, and the test samples."""
    sizes = [len(v) for e in report.models for k, v in e.per_sample.items() if k.startswith("rmse/")]
    strips = max(sizes, default=0)
    if not report.per_material_on:
        return strips, strips
    return len({m for g in report.groups for m in g}), len(report.groups)


def _per_strip(report: Report, model: str, versus: str, column: str) -> Difference | None:
    """The paired bootstrap over strips of one comparison, on a grouped test set of few materials."""
    from ..metrics import paired_difference

    units, _ = unit_count(report)
    if not report.per_material_on or units >= SMALL_SAMPLE:
        return None
    rows = {e.label: e for e in report.models}
    a, b = rows[model].per_sample.get(f"rmse/{column}"), rows[versus].per_sample.get(f"rmse/{column}")
    return None if a is None or b is None else paired_difference(a, b)


def family(report: Report) -> Family:
    """The report's verdicts (against the baselines, between models, then across seeds and
    budgets: :func:`svbrdf_bench.report.seedstats.stated`), Holm-corrected together."""
    from ..metrics import holm_adjusted

    # Every section of a report asks for the family (tables, words, files, the seeds section): the
    # bootstraps behind it run once per set of rows (the rows' figures held, compared by identity).
    rows_now = [(e.label, e.run_id, e.per_sample, e.figures) for e in report.models]
    cached = report._family_cache
    same = cached and cached["groups"] is report.groups and len(cached["rows"]) == len(rows_now)
    if same and all(a[:2] == b[:2] and a[2] is b[2] and a[3] is b[3]
                    for a, b in zip(cached["rows"], rows_now, strict=True)):  # fmt: skip
        return cached["family"]
    raw = [("against baseline", r["model"], r["versus"], r["column"], r["rmse_difference"], r["low"],
            r["high"], r["verdict"], r["p_value"]) for r in report.against_reference()]  # fmt: skip
    raw += [("between models", c["model"], c["versus"], "render", c["render_rmse_difference"], c["low"],
             c["high"], "within noise" if c["within_noise"] else BETTER, c["p_value"])
            for c in (report.costs() if len(report.costed) > 1 else [])]  # fmt: skip
    rows = len(raw)  # the rows' own verdicts; those across seeds and budgets have no per-strip twin
    raw += [(r["kind"], r["model"], r["versus"], "render", r["rmse_difference"], r["low"], r["high"],
             r["verdict"], r["p_value"]) for r in stated(report)]  # fmt: skip
    adjusted = holm_adjusted([r[-1] for r in raw])
    verdicts = [
        Verdict(*r, holm_p=q, strips=_per_strip(report, *r[1:4]) if i < rows else None)
        for i, (r, q) in enumerate(zip(raw, adjusted, strict=True))
    ]
    out = Family(verdicts, names={e.label: e.short for e in report.models})
    report._family_cache.update(rows=rows_now, groups=report.groups, family=out)
    return out


def small_sample_note(report: Report) -> str | None:
    """A warning in words when the test set has fewer than :data:`SMALL_SAMPLE` materials; None else."""
    units, strips = unit_count(report)
    if units == 0 or units >= SMALL_SAMPLE:
        return None
    what = "materials" if report.per_material_on else "test images (each its own material)"
    unit = "materials" if report.per_material_on else "images"
    distinct = math.comb(2 * units - 1, units)
    beside = (
        f"Per-strip intervals (the same paired bootstrap over the {strips} strips: more units, but not "
        "independent ones, for strips share materials) stand beside the per-material ones in the table "
        "of verdicts: trust a verdict only where both agree, and add materials before leaning on it."
        if report.per_material_on
        else "Add test materials before leaning on any verdict."
    )
    return (
        f"SMALL SAMPLE: {units} {what}, fewer than {SMALL_SAMPLE}: intervals and verdicts over so few "
        f"groups are unreliable. A bootstrap over {units} {unit} has only {distinct} distinct resamples; "
        f"when all {units} move the same way the interval collapses onto the mean (e.g. \"+2% [+2, +2]\") "
        f"and its p-value to 0, where an exact sign test on {units} {unit} could not go below "
        f"p = {2.0 ** (1 - units):.3g}. "
        + beside
    )


def holm_note(fam: Family) -> str | None:
    """How many comparisons the report makes, and which verdicts Holm overturns; None without any."""
    if not fam.count:
        return None
    decided = [v for v in fam.verdicts if v.decided]
    gone = fam.overturned()
    head = (
        f"{fam.count} comparisons (verdicts) in this report, each a 95% paired bootstrap; corrected "
        f"together by Holm at {ALPHA:.0%} (p: twice the share of resamples on the far side of 0)"
    )
    if not decided:
        return f"{head}: none is beyond noise, so none to correct."
    if not gone:
        return f"{head}: all {len(decided)} verdicts beyond noise survive."
    names = ", ".join(f"{fam.pair(v)} on {v.column}" for v in gone)
    return f"{head}: {len(gone)} of the {len(decided)} verdicts beyond noise do not survive ({names})."


def holm_clause(fam: Family, model: str) -> str:
    """For the headline: the verdicts of ``model`` that Holm overturns, as a sentence ('' if none)."""
    gone = fam.overturned(model)
    if not gone:
        return ""
    what = ", ".join(f"{v.column} ({v.verdict})" for v in gone)
    return f" After Holm over {fam.count} comparisons, its verdicts on {what} do not hold."
