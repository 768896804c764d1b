"""Benchmark reports, built from MLflow alone (so ``svbrdf-bench report PARENT`` rebuilds them).

Tables in the layout of the paper's Tables 1-4 (rows = models, then the untrained baselines
``mean`` and ``photo``; columns = the four maps and the renderings), one per metric, each figure
with its 95% bootstrap interval over test images; on a real test set (strips with the materials
the parent's ``eval/test_groups.json`` records) each figure is the mean over source materials of
the per-material means (a Des18 strip counts for both its materials), intervals and paired
comparisons resampling materials (:func:`svbrdf_train.per_material`); whether each trained model
beats the constant-map baseline ``mean``, map by map (paired bootstrap of the RMSE difference),
which the headline repeats in words; the time table (training time on the budget clock and wall
time, throughput, latency, parameters, memory); and what each trained model's extra accuracy costs
against each other one, saying when the difference lies within noise.

Timings are medians with their interquartile range, ``19.3 [0.8]`` (:mod:`svbrdf_bench.timing`);
when the machine's load while a latency was measured makes it unreliable (a thread of the timing
waited for a CPU more than :data:`~svbrdf_bench.timing.CPU_WAIT_LIMIT` of the time), the report
says so in words at its top. The Pareto front of render RMSE against latency is noise-aware: a
model is dominated when a faster one's render RMSE is lower or within noise of its own (the
same 95% paired bootstrap as the other comparisons), so it is on the front only if it is faster
or better beyond noise (:meth:`Report.latency_front`).

Reference rows (model files trained elsewhere: ``--from-models``, ``--models pretrained``) stand in
every table under a label that gives their budget and says they are not equal-budget; where the
report speaks of budgets and costs (the header, the clock, the time table, what accuracy costs,
the plots) they are named ``NAME (reference)`` and a note says their training figures are what
their files record.

With ``--refine 0,N,...`` each row is followed by its refined rows, ``<row> +refine N`` (its maps
refined for N steps against each test photo); ``mean +refine N`` is named the pure-optimisation
baseline, and each refined model is held against it (not against the unrefined ``mean``): what
the network adds over optimisation alone at the same budget. A table and a plot
(``accuracy_vs_capture_time.png``) set accuracy against seconds per image. With ``--real-data``
too, the real-photo table holds the refined rows (with a note that re-rendering the photo is what
refinement optimises) and ``real_comparison.png`` shows their maps under their model's.

The runs are read as :mod:`svbrdf_bench.layout` describes them; this package never imports the
runner that writes them. It keeps the figures apart from how they are shown:

- :mod:`~svbrdf_bench.report.rows`: one row (:class:`ModelEntry`) and the columns every table shares;
- :mod:`~svbrdf_bench.report.figures`: :class:`Report`, every number (intervals, verdicts against
  ``mean``, costs, the latency front, one record per row);
- :mod:`~svbrdf_bench.report.words`: the headline and the notes, as sentences;
- :mod:`~svbrdf_bench.report.verdicts`: every verdict of the report as one family, Holm-corrected
  for their number (:func:`family`), and the warning for a test set of few materials, with
  per-strip intervals beside the per-material ones;
- :mod:`~svbrdf_bench.report.tables`: each table as data (:class:`~svbrdf_bench.report.tables.Table`);
- :mod:`~svbrdf_bench.report.seeds`: "Across seeds and budgets" (``--seeds N``, ``--minutes
  2,8,32``): each model at each budget over its seeds, the hierarchical bootstrap, the verdicts;
- :mod:`~svbrdf_bench.report.text`: the renderers, :func:`terminal` and :func:`markdown`;
- :mod:`~svbrdf_bench.report.files`: the report folder (:func:`write_report`: Markdown, CSV,
  JSON, plots);
- :mod:`~svbrdf_bench.report.read`: :func:`build_report`, the report read back from MLflow;
- :mod:`~svbrdf_bench.report.published`: published numbers (``--published FILE.yaml``) beside the
  rows, never rows of their own, and their protocol against this benchmark's scoring;
- :mod:`~svbrdf_bench.report.export`: :func:`export_table`, the RMSE table as a paper prints it
  (``svbrdf-bench export``: Markdown or LaTeX).
"""

from __future__ import annotations

from .export import EXPORT_FORMATS, export_table
from .figures import Report
from .files import csv_text, results_json, write_report
from .read import build_report, link_refined
from .rows import COLUMNS, PURE_OPTIMISATION, REFERENCE, ModelEntry
from .tables import Table
from .text import markdown, table_lines, terminal
from .verdicts import Family, Verdict, family, small_sample_note
from .words import (
    REAL_CAVEAT,
    REAL_REFINED_CAVEAT,
    averaging_note,
    clock_note,
    headline,
    timing_notes,
    timing_warning,
)

__all__ = [
    "Report",
    "ModelEntry",
    "build_report",
    "write_report",
    "terminal",
    "markdown",
    "csv_text",
    "results_json",
    "link_refined",
    "Table",
    "table_lines",
    "family",
    "Family",
    "Verdict",
    "small_sample_note",
    "export_table",
    "EXPORT_FORMATS",
    "headline",
    "averaging_note",
    "clock_note",
    "timing_warning",
    "timing_notes",
    "COLUMNS",
    "REFERENCE",
    "PURE_OPTIMISATION",
    "REAL_CAVEAT",
    "REAL_REFINED_CAVEAT",
]
