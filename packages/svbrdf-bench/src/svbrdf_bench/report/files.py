"""The report folder: report.md (:func:`~svbrdf_bench.report.text.markdown`), results.json (every
figure and word of the report, and the per-strip values), results.csv, costs.csv,
against_mean.csv (:func:`csv_text`), the plots (:mod:`svbrdf_bench.plots`) and the comparison
sheets. Every file is written whole or not at all (``svbrdf_render.plumbing``).
"""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
from pathlib import Path

from svbrdf_render.plumbing import atomic_output, write_text

from ..layout import SECONDS_PER_IMAGE
from . import seeds, words
from .figures import Report
from .published import published_json
from .rows import PURE_OPTIMISATION, REFERENCE
from .text import markdown
from .verdicts import ALPHA, Family, family, holm_note, small_sample_note

__all__ = ["write_report", "csv_text", "results_json", "comparisons_json"]


def csv_text(rows: list[dict], columns: list[str] | None = None) -> str:
    """Rows as CSV text (columns: every key met, in order, unless given; None as empty)."""
    keys = columns or list(dict.fromkeys(k for r in rows for k in r))
    buffer = io.StringIO(newline="")
    w = csv.DictWriter(buffer, fieldnames=keys, extrasaction="ignore")
    w.writeheader()
    w.writerows({k: "" if r.get(k) is None else r[k] for k in keys} for r in rows)
    return buffer.getvalue()


def results_json(report: Report, records: list[dict], costs: list[dict], against: list[dict]) -> dict:
    """results.json: the parent run, the words of the report, every row's record, the comparisons
    with ``mean`` and between models, the latency front and the per-strip values."""
    front = report.latency_front()
    return {
        "parent_run": report.parent_id,
        "preset": report.preset,
        "test_set": report.test_set,
        "averaged_over": report.unit,
        "averaging": words.averaging_note(report),
        "headline": words.headline(report),
        "budget_clock": words.clock_note(report),
        "models": records,
        "against_mean": against,
        "costs": costs,
        "timing_warning": words.timing_warning(report),
        "timing_notes": words.timing_notes(report),
        "latency_front": {
            "front": front["front"],
            "dominated": front["dominated"],
            "within_noise": [list(p) for p in front["within_noise"]],
        },  # fmt: skip
        "per_strip": report.per_strip_json(),
        "small_sample": small_sample_note(report),
        "comparisons": comparisons_json(family(report)),
        "across_seeds": seeds.section_json(report),  # None: one seed and one budget per model
        "published": published_json(report),  # None: no --published numbers
    }


def comparisons_json(fam: Family) -> dict:
    """results.json's ``comparisons``: every verdict with its p-value, Holm-adjusted p and whether it
    survives, and the per-strip interval where the test set has few materials."""
    rows = []
    for v in fam.verdicts:
        row = {"kind": v.kind, "model": v.model, "versus": v.versus, "column": v.column,
               "rmse_difference": v.difference, "low": v.low, "high": v.high, "verdict": v.verdict,
               "p_value": v.p_value, "holm_p": v.holm_p, "survives_holm": v.survives,
               "words": fam.words(v)}  # fmt: skip
        if v.strips is not None:
            d = v.strips
            row["per_strip"] = {"rmse_difference": d.mean, "low": d.low, "high": d.high,
                                "verdict": d.verdict()}  # fmt: skip
        rows.append(row)
    return {"count": fam.count, "alpha": ALPHA, "method": "holm", "note": holm_note(fam), "verdicts": rows}


def _capture_series(report: Report) -> tuple[dict[str, list], set[str]]:
    """``{row: [(seconds per image, steps, {column: (mean, low, high)})]}`` through its budgets,
    for :func:`~svbrdf_bench.plots.accuracy_vs_capture_time`, and the names of the baselines'
    lines (``mean``'s is named the pure-optimisation baseline); empty without refined rows."""
    if not report.refined:
        return {}, set()
    series: dict[str, list] = {}
    baselines = set()
    for e in report.models:
        seconds = e.figures.get(SECONDS_PER_IMAGE, math.nan)
        cis = {c: report.interval(e, "rmse", c) for c in ("render", "diffuse")}
        if math.isnan(seconds) or any(ci is None for ci in cis.values()):
            continue
        base = next((m for m in report.models if m.label == e.family and not m.refine_steps), e)
        name = (
            f"{base.label} ({PURE_OPTIMISATION} when refined)"
            if base.label == REFERENCE and e.baseline
            else base.short
        )
        if e.baseline:
            baselines.add(name)
        series.setdefault(name, []).append((seconds, e.refine_steps, cis))
    return series, baselines


def _plots(report: Report, out: Path) -> dict[str, Path]:
    """The plots that have something to show: ``{key of text.PLOTS: file written}``."""
    from ..plots import accuracy_vs_capture_time, accuracy_vs_training_time, learning_curves, pareto

    written = {}
    curves = {e.label: e.curve for e in report.models if e.curve[0]}
    real_curves = {e.label: e.curve_real for e in report.models if e.curve_real[0]}
    if curves or real_curves:
        written["learning_curves"] = learning_curves(
            curves, out / "learning_curves.png", real=real_curves, xlabel="training time, budget clock (s)"
        )
    front = report.latency_front()
    if front["points"]:
        written["pareto"] = pareto(front["points"], out / "pareto.png", within_noise=front["within_noise"])
    if series := seeds.training_time_series(report):  # several seeds or budgets
        written["training_time"] = accuracy_vs_training_time(series, out / "accuracy_vs_training_time.png")
    series, baselines = _capture_series(report)
    if series:
        target = out / "accuracy_vs_capture_time.png"
        written["capture_time"] = accuracy_vs_capture_time(series, target, baselines=baselines)
    return written


def _copy(source: Path, target: Path) -> Path:
    """``source`` copied to ``target`` (whole or not at all), unless it is already there."""
    if Path(source) != target:
        with atomic_output(target) as tmp:
            shutil.copyfile(source, tmp)
    return target


def write_report(
    report: Report, out: str | Path, *, grid: Path | None = None, real_grid: Path | None = None
) -> list[Path]:
    """``report.md``, ``results.csv``, ``results.json``, ``costs.csv``, the plots and the grid;
    ``real_grid``: the real-photo sheet (``--real-data`` with ``--refine``), as ``real_comparison.png``.
    Returns the files written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    images = _plots(report, out)
    for key, sheet in (("comparison", grid), ("real_comparison", real_grid)):
        if sheet is not None:
            images[key] = _copy(sheet, out / f"{key}.png")
    records = report.records()
    costs = report.costs() if len(report.costed) > 1 else []
    against = report.against_reference()
    write_text(out / "results.json", json.dumps(results_json(report, records, costs, against), indent=2))
    written = [*images.values(), out / "results.json"]
    for name, rows in (("results.csv", records), ("costs.csv", costs), ("against_mean.csv", against)):
        if rows:
            write_text(out / name, csv_text(rows))
            written.append(out / name)
    write_text(out / "report.md", markdown(report, {key: path.name for key, path in images.items()}))
    return [*written, out / "report.md"]
