"""The report as text: :func:`terminal` (what ``svbrdf-bench run`` and ``report`` print: tables in
aligned columns) and :func:`markdown` (report.md: pipe tables, the plots as images). Both show
the same tables (:mod:`~svbrdf_bench.report.tables`) and words (:mod:`~svbrdf_bench.report.words`)
in the same order: the headline, the notes, then the tables.
"""

from __future__ import annotations

from . import seeds, words
from .figures import Report
from .tables import (
    Table,
    accuracy_table,
    against_table,
    cost_table,
    phase_table,
    real_table,
    refine_table,
    time_table,
    verdict_table,
)
from .inference import inference_table
from .published import protocol_table, rescored_table, with_published
from .verdicts import family, holm_note, small_sample_note

__all__ = ["terminal", "markdown", "table_lines", "PLOTS"]

#: The plots and images report.md shows, in order: the key of ``files`` -> caption.
PLOTS = (
    ("learning_curves", "Validation render RMSE against training time"),  # dashed: real materials
    ("pareto", "Inference latency against render RMSE"),
    ("training_time", "Test render RMSE against training minutes (mean over seeds, 95% interval "
     "resampling seeds, then materials)"),
    ("capture_time", "Render and diffuse RMSE against seconds per image (network + refinement)"),
    ("comparison", "Input, true maps and each model's maps, with flash re-renderings"),
    ("real_comparison", "Real photos: each model's maps and their re-rendering under the fitted "
     "flash, each refined version under its model's (re-rendering the photo's own view is what "
     "refinement optimises)"),
)  # fmt: skip


def table_lines(table: Table | None, markdown: bool) -> list[str]:
    """A table as lines: a Markdown section with a pipe table, or a title over aligned columns;
    then its ``after`` lines. None (a table with nothing to show): no lines."""
    if table is None:
        return []
    head, rows = table.head, table.rows
    if markdown:
        return [
            f"## {table.title}",
            "",
            "| " + " | ".join(head) + " |",
            "| " + " | ".join("---" for _ in head) + " |",
            *("| " + " | ".join(r) + " |" for r in rows),
            *table.after,
        ]
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines = [table.title, fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    return [*lines, *(fmt.format(*r) for r in rows), *table.after]


def _tables(report: Report, markdown: bool) -> list[str]:
    """Every table, each followed by an empty line: accuracy per metric, against ``mean``, real
    photos, refinement, time (with the timing notes), inference cost, what accuracy costs, every
    verdict with its Holm correction, the Pareto front."""
    fam = family(report)
    blocks = [table_lines(with_published(accuracy_table(report, *m), report, m[0]), markdown)
              for m in report.metrics_present()]  # fmt: skip
    blocks.append(table_lines(protocol_table(report), markdown))  # --published: their protocol and ours
    blocks.append(table_lines(rescored_table(report), markdown))  # --published with a scorer
    blocks += [table_lines(t, markdown) for t in (against_table(report, fam), real_table(report))]
    blocks += [table_lines(refine_table(report), markdown), table_lines(time_table(report), markdown)]
    blocks.append([f"- {n}" if markdown else n for n in words.timing_notes(report)])
    blocks.append(table_lines(inference_table(report), markdown))
    if len(report.costed) > 1:
        blocks.append(table_lines(cost_table(report, fam), markdown))
    blocks.append(table_lines(verdict_table(report, fam), markdown))
    blocks.append(words.front_lines(report))
    blocks.append(table_lines(seeds.seeds_table(report), markdown))  # several seeds or budgets
    blocks.append(table_lines(phase_table(report), markdown))
    return [line for block in blocks if block for line in (*block, "")]


def _trust_notes(report: Report) -> list[str]:
    """After the other notes: a warning when the test set has few materials, and how many
    comparisons the report makes and which Holm overturns."""
    return [line for line in (small_sample_note(report), holm_note(family(report))) if line]


def terminal(report: Report) -> str:
    """The report in the terminal: the rows, the headline and notes, then the tables."""
    note, refine = words.reference_note(report), words.refine_note(report)
    names = ", ".join(e.name for e in report.models)
    lines = [
        f"svbrdf-bench: {names} ({report.preset}; {words.budget_words(report)})",
        *words.headline(report),
        f"test set: {report.test_set}; {report.lpips_note}",
        words.averaging_note(report),
        words.clock_note(report),
        *([warning] if (warning := words.timing_warning(report)) else []),
        *words.init_notes(report),
        *([note] if note else []),
        *([refine] if refine else []),
        *_trust_notes(report),
        "",
        *_tables(report, False),
    ]
    return "\n".join(lines).rstrip("\n")


def markdown(report: Report, files: dict[str, str]) -> str:
    """report.md: the headline in bold, the notes as a list, the tables, then the images of
    ``files`` (``{key of PLOTS: file name}``) that were written."""
    warning, small = words.timing_warning(report), small_sample_note(report)
    lines = [
        f"# Benchmark: {', '.join(e.name for e in report.models)}",
        "",
        *(line for h in words.headline(report) for line in (f"**{h}**", "")),
        *((f"**{warning}**", "") if warning else ()),
        *((f"**{small}**", "") if small else ()),
        f"- preset: {report.preset} ({words.budget_words(report)})",
        f"- {words.clock_note(report)}",
        *(f"- {line}" for line in words.init_notes(report)),
        *(f"- {line}" for line in [words.reference_note(report)] if line),
        *(f"- {line}" for line in [words.refine_note(report)] if line),
        f"- test set: {report.test_set}",
        f"- {words.averaging_note(report)}",
        *(f"- {line}" for line in [holm_note(family(report))] if line),
        f"- {report.lpips_note}",
        f"- MLflow parent run: `{report.parent_id}`; rebuild with `svbrdf-bench report {report.parent_id}`",
        "",
        *_tables(report, True),
    ]
    for name, caption in PLOTS:
        if name in files:
            lines += [f"## {caption}", "", f"![{caption}]({files[name]})", ""]
    return "\n".join(lines)
