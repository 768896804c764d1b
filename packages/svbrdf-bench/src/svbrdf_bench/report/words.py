"""The report in words: the headline (whether each trained model beats the constant-map
baseline ``mean``), the notes on budgets, clocks, reference and refined rows, the averaging, the
timings and the load while they were measured, the Pareto front and what accuracy costs.

Each function takes a :class:`~svbrdf_bench.report.figures.Report` and returns sentences without
markup; the terminal, Markdown and JSON renderers all show the same ones.
"""

from __future__ import annotations

import math

from ..layout import REFINE_BACKEND_PARAM, REFINE_FLASH_PARAM
from ..timing import CPU_WAIT_LIMIT, LATENCY_METRIC, SPREAD_LIMIT, Load
from .figures import Report
from .rows import CLOCK_WORDS, PURE_OPTIMISATION, REFERENCE, ModelEntry
from .verdicts import family, holm_clause

__all__ = [
    "headline",
    "budget_words",
    "clock_note",
    "init_notes",
    "reference_note",
    "refine_note",
    "averaging_note",
    "timing_warning",
    "timing_notes",
    "front_lines",
    "cost_notes",
    "ratio",
    "REAL_CAVEAT",
    "REAL_REFINED_CAVEAT",
]

REAL_CAVEAT = (
    "Re-rendering RMSE measures consistency with the photo, not correctness: copying the photo into the "
    "diffuse map (the `photo` baseline) scores well without recovering any material."
)

#: Under the real-photo table when it holds refined rows (``--real-data`` with ``--refine``).
REAL_REFINED_CAVEAT = (
    "Refined rows (`+refine N`) had their maps of each real photo optimised to re-render that very "
    "photo: the re-rendering of the photo's own view is what refinement optimises, so their low "
    "re-render RMSE here holds by construction and is no evidence of accuracy (accuracy is measured "
    "on the test set only, against true maps)."
)


def averaging_note(report: Report) -> str:
    """How many strips and materials the tables are over, and how they are averaged."""
    if not report.per_material_on:
        n = len(next(iter(report.models)).per_sample.get("rmse/render", ())) if report.models else 0
        return (
            f"tables over {n} test images, each its own material (mean over images; "
            "95% bootstrap intervals over images)"
        )
    materials = sorted({m for g in report.groups for m in g})
    how = (
        "a Des18 strip counts for both materials its name gives"
        if report.group_by == "des18"
        else "one material per file"
    )
    return (
        f"tables over {len(report.groups)} strips of {len(materials)} materials ({how}): each figure is "
        "the mean over materials of the mean over each material's strips, so every material weighs "
        "alike; bootstrap intervals and paired comparisons resample materials; per-strip figures "
        "are in results.json"
    )


def refine_note(report: Report) -> str | None:
    """What the refined rows are, and which row is the pure-optimisation baseline."""
    if not report.refined:
        return None
    budgets = sorted({e.refine_steps for e in report.refined})
    how = ", ".join(
        f"{what} {report.refine[key]}"
        for key, what in ((REFINE_BACKEND_PARAM, "backend"), (REFINE_FLASH_PARAM, "flash"))
        if key in report.refine
    )
    pure = (
        f"; `{REFERENCE} +refine N` refines constant maps: the {PURE_OPTIMISATION}, optimisation alone, "
        "and each refined model is held against it at the same N (what the network adds over it)"
        if any(e.pure_optimisation for e in report.refined)
        else ""
    )
    return (
        f"refined rows (`+refine N`): each row's maps refined by svbrdf_render.refine_maps for N Adam "
        f"steps against each test photo (N = {', '.join(map(str, budgets))}"
        + (f"; {how}" if how else "")
        + f"), then scored alike{pure}; s/image: network forward plus refinement (flash finding "
        "included), one image at a time"
    )


def budget_words(report: Report) -> str:
    """The training budget in words; says that reference rows keep their own."""
    if report.reference_rows and report.competitors:
        return f"{report.minutes}; reference rows: their own budgets, not equal"
    return report.minutes


def reference_note(report: Report) -> str | None:
    """What the reference rows are: trained elsewhere, figures from their files, not competitors."""
    if not report.reference_rows:
        return None
    files = "; ".join(
        f"{e.short} = {e.budget.get('source', '?')} (SHA-256 {e.budget.get('sha256', '?')[:12]})"
        for e in report.reference_rows
    )
    return (
        "reference rows are model files trained elsewhere, scored on the same test images: their "
        "training time and steps are what each file records (its own budget and hardware), not "
        f"this benchmark's, so they are no equal-budget competitors: {files}"
    )


def headline(report: Report) -> list[str]:
    """What a reader must see first: per trained model, whether it beats the constant maps, and
    which of those verdicts do not survive Holm over the report's comparisons."""
    if report.reference() is None:
        if report.baselines in ("-", ""):
            return ["No baseline was evaluated (--no-baselines): nothing here says whether the models "
                    "beat constant maps derived from the photo."]  # fmt: skip
        return []
    synthetic = "procedural" in report.test_set
    lines = []
    failing, fam = report.not_beating(), family(report)
    for e in report.trained:
        label, rows, ref = e.label, failing[e.label], report.reference(e.refine_steps)
        if ref is None:
            continue
        if e.refine_steps:
            lines.append(_refined_headline(e, ref, rows) + holm_clause(fam, label))
            continue
        if not rows:
            lines.append(f"{label} beats the constant-map baseline `{REFERENCE}` on every map and on "
                         "renderings (RMSE, 95% paired bootstrap)." + holm_clause(fam, label))  # fmt: skip
            continue
        cols = [r["column"] for r in rows]
        worse = [r["column"] for r in rows if r["verdict"] == "worse"]
        noise = [r["column"] for r in rows if r["verdict"] == "within noise"]
        why = "; ".join(
            part for part in (f"worse on {', '.join(worse)}" if worse else "",
                              f"within noise on {', '.join(noise)}" if noise else "") if part
        )  # fmt: skip
        where = (
            "there that constant maps do not already give, even on synthetic test images"
            if synthetic
            else "that transfers there"
        )
        lines.append(
            f"{label} does NOT beat the constant-map baseline `{REFERENCE}` on {', '.join(cols)}: it has "
            f"learned nothing {where} ({why})." + holm_clause(fam, label)
        )
    return lines


def _refined_headline(e: ModelEntry, ref: ModelEntry, rows: list[dict]) -> str:
    """A refined row against the pure-optimisation baseline at the same budget, in words."""
    what = f"the {PURE_OPTIMISATION} `{ref.label}`"
    if not rows:
        return f"{e.label} beats {what} on every map and on renderings (RMSE, 95% paired bootstrap)."
    worse = [r["column"] for r in rows if r["verdict"] == "worse"]
    noise = [r["column"] for r in rows if r["verdict"] == "within noise"]
    parts = (
        f"worse on {', '.join(worse)}" if worse else "",
        f"within noise on {', '.join(noise)}" if noise else "",
    )
    why = "; ".join(part for part in parts if part)
    return (
        f"{e.label} does NOT beat {what} on {', '.join(r['column'] for r in rows)}: refining constant "
        f"maps for as many steps does as well there, the network adds nothing ({why})."
    )


def clock_note(report: Report) -> str:
    """Which clock budgeted the trained models' training time (reference rows: not this budget)."""
    trained = report.competitors
    if not trained:
        return "no model trained at this benchmark's budget" if report.trained else "no trained model"
    words = {
        e.label: CLOCK_WORDS.get(e.clock, f"{e.clock} clock") if e.clock else "wall clock (none recorded)"
        for e in trained
    }
    if len(set(words.values())) == 1:
        return f"training time budgeted and reported on the {next(iter(words.values()))}"
    return "training time budgeted and reported on " + "; ".join(
        f"{label}: the {w}" for label, w in words.items()
    )


def init_notes(report: Report) -> list[str]:
    """One line per fine-tuned model: where it started and the training time before."""
    return [
        f"{e.label} was fine-tuned from {e.init[0]} (fit --init), which had trained {e.init[1]:.0f} s "
        "on the same clock: its learning curve starts there, and its whole training time is that "
        "plus the time table's"
        for e in report.competitors
        if e.init is not None
    ]


def timing_warning(report: Report) -> str | None:
    """A warning in words when the load while a latency was measured makes it unreliable."""
    loads = {k: v for k, v in report.latency_loads().items() if v is not None and v.unreliable}
    if not loads:
        return None
    worst_name, worst = max(loads.items(), key=_worst_load)
    return (
        f"TIMINGS UNRELIABLE: the machine was busy while the latency of {', '.join(loads)} was measured "
        f"(worst, {worst_name}: {worst.words()}). A time measured while its thread waits for a CPU "
        f"more than {100 * CPU_WAIT_LIMIT:.0f}% of the time is inflated by more than "
        f"{100 * CPU_WAIT_LIMIT / (1 - CPU_WAIT_LIMIT):.0f}%, more than the spread expected on an idle "
        f"machine (an IQR under {100 * SPREAD_LIMIT:.0f}% of the median), "
        "and by an amount that depends on what else ran at that moment: these latencies, their ratios "
        "and the Pareto front cannot be compared. Rerun on an idle machine (`svbrdf-bench run "
        "--from-runs ...` times the fits again without retraining them)."
    )


def timing_notes(report: Report) -> list[str]:
    """How the times were measured, the load while they were, and which spreads are wide."""
    timed = report.timed()
    if not timed:
        return []
    runs = sorted({int(e.figures[f"{LATENCY_METRIC}_runs"]) for e in timed
                   if f"{LATENCY_METRIC}_runs" in e.figures})  # fmt: skip
    how = f"{'/'.join(map(str, runs))} timed runs" if runs else "timed runs"
    lines = [
        f"latency: median [interquartile range] of {how} on one 256x256 image, after 3 warm-up runs; "
        "train ms/step: median [IQR] over the fit's logging windows (budget clock), where logged"
    ]
    loads = report.latency_loads()
    read = {k: v for k, v in loads.items() if v is not None}
    if not read:
        lines.append("the machine's load while timing was not recorded (an older run): nothing checks "
                     "these latencies")  # fmt: skip
    elif timing_warning(report) is None:
        worst_name, worst = max(read.items(), key=_worst_load)
        verdict = (
            f"under the {100 * CPU_WAIT_LIMIT:.0f}% limit of time waiting for a CPU"
            if worst.cpu_wait is not None
            else "not above one runnable task per CPU"
            if worst.unreliable is False
            else "not measurable on this system"
        )
        lines.append(f"load while timing (worst, {worst_name}): {worst.words()}; {verdict}")
    wide = []
    for e in timed:
        median, iqr = e.figures["time/latency_ms"], e.figures.get("time/latency_iqr_ms", math.nan)
        if median > 0 and iqr / median > SPREAD_LIMIT:
            wide.append(f"{e.short} ({100 * iqr / median:.0f}%)")
    if wide:
        lines.append(
            f"wide spread (IQR over {100 * SPREAD_LIMIT:.0f}% of the median latency): {', '.join(wide)}"
        )
    return lines


def front_lines(report: Report) -> list[str]:
    """The front in words: who is on it, and why each other row is not."""
    pf = report.latency_front()
    if len(pf["points"]) < 2:
        return []
    ties = {frozenset(p) for p in pf["within_noise"]}
    why = []
    for name, by in pf["dominated"].items():
        (xa, ya), (xb, yb) = pf["points"][name][:2], pf["points"][by][:2]
        speed = "faster" if xb < xa else "as fast"
        accuracy = (
            "within noise of it in render RMSE" if frozenset((name, by)) in ties
            else "more accurate beyond noise" if yb < ya else "as accurate"
        )  # fmt: skip
        why.append(f"{name} ({by} is {speed} and {accuracy})")
    lines = [
        "Latency against render RMSE: on the Pareto front (faster than, or more accurate beyond noise "
        f"than, every row at least as fast; 95% paired bootstrap): {', '.join(pf['front'])}"
        + (f"; dominated: {'; '.join(why)}" if why else "")
        + "."
    ]
    if timing_warning(report):
        lines.append("The latencies were measured on a busy machine (see the warning above), and so was "
                     "this front.")  # fmt: skip
    return lines


def cost_notes(report: Report, costs: list[dict]) -> list[str]:
    """Under the table of what accuracy costs: each pair in words (a reference row's pair says it is
    no equal-budget comparison), then which of the compared models do not beat ``mean`` on
    renderings."""
    notes = []
    short = {e.label: e.short for e in report.costed}
    fam = family(report)
    for c in costs:
        v = fam.get(c["model"], c["versus"], "render")
        holm = "" if v is None or v.survives else f", but not after Holm over {fam.count} comparisons"
        after = f"{holm}," if holm else ""
        a, b = short[c["model"]], short[c["versus"]]
        if c["reference"]:
            difference = (
                "a render RMSE difference within the noise of this test set"
                if c["within_noise"]
                else f"{-c['render_rmse_difference']:.4f} render RMSE better{holm}"
            )
            notes.append(
                f"{a} against {b}: {difference}, at {ratio(c['latency_ratio'])} the latency and "
                f"{ratio(c['params_ratio'])} the parameters; a reference row trained on its own "
                "budget, so this is no comparison at equal training cost."
            )
        elif c["within_noise"]:
            notes.append(
                f"{c['model']} and {c['versus']}: the render RMSE difference lies within the noise of "
                f"this test set (its interval contains 0); the extra cost buys no measurable accuracy."
            )
        else:
            notes.append(
                f"{c['model']} renders {-c['render_rmse_difference']:.4f} RMSE better than "
                f"{c['versus']}{after} "
                f"for {ratio(c['train_time_per_step_ratio'])} the training time per step and "
                f"{ratio(c['latency_ratio'])} the latency."
            )
    failing = {m for m, rows in report.not_beating().items() if any(r["column"] == "render" for r in rows)}
    pairs = dict.fromkeys(x for c in costs for x in (c["model"], c["versus"]))
    compared = [short[m] for m in pairs if m in failing]
    if compared:
        notes.append(
            f"{', '.join(compared)} {'does' if len(compared) == 1 else 'do'} not beat the constant-map "
            f"baseline `{REFERENCE}` on renderings: what these pairs trade against time is accuracy "
            "a constant map already has."
        )
    return notes


def ratio(x: float) -> str:
    """A ratio of two figures as ``1.50x``; ``-`` when it could not be computed."""
    return "-" if x is None or math.isnan(x) else f"{x:.2f}x"


def _worst_load(item: tuple[str, Load]) -> tuple[float, float]:
    """Sort key of ``(row, load)``: the longest wait for a CPU, then the load average."""
    return (item[1].cpu_wait or 0.0, item[1].load_average or 0.0)
