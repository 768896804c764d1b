"""The comparison table as a paper prints it (``svbrdf-bench export``): rows = the models, then the
constant-map baselines; columns = the RMSE of each map and of the renderings, each with its 95%
interval; the best figure of each column in bold; a caption naming the test set, its number of
materials, the seeds and the protocol. In Markdown (a pipe table under a caption line) or
LaTeX (a booktabs ``tabular`` inside a ``table``). With several seeds (``--seeds N``) or
budgets per model, a model is one row per budget over its seeds, as the report's section
"Across seeds and budgets" gives it (:mod:`~svbrdf_bench.report.seeds`).

Published numbers (``--published``) follow, marked "published, not rerun": copied figures, with
no interval, never in bold, and a caption sentence naming where their protocol differs from this
table's (:mod:`~svbrdf_bench.report.published`). When the file has a ``scorer``, this table's
models scored again that way (marked "scored as published", maps only) stand between the two.

Figures are the report's own (:meth:`Report.interval`), printed to 3 decimals as the paper's
Table 1 prints them; "best" is the lowest mean at that precision, so rows that print alike are
bold alike.
"""

from __future__ import annotations

from .figures import Report
from .published import export_rescored, export_rows, export_words
from .rows import COLUMNS, PURE_OPTIMISATION, REFERENCE, ModelEntry
from .verdicts import unit_count

__all__ = ["EXPORT_FORMATS", "check_format", "export_table", "caption", "seed_count", "latex_escape"]

#: The formats of :func:`export_table`.
EXPORT_FORMATS = ("latex", "markdown")
#: Decimals of the figures, as the paper's tables print RMSE (.062).
DIGITS = 3
#: What each untrained baseline is, for the caption.
BASELINE_WORDS = {
    REFERENCE: "constant maps from the photo's median",
    "photo": "the photo, its flash fall-off divided out, as diffuse",
}
_LATEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
          "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}  # fmt: skip


def latex_escape(text: str) -> str:
    """``text`` with LaTeX's special characters escaped; a `code span` becomes ``\\texttt{...}``.

    >>> latex_escape("no_attn: -12% of `mean`")
    'no\\\\_attn: -12\\\\% of \\\\texttt{mean}'
    """
    out = "".join(_LATEX.get(ch, ch) for ch in text)
    parts = out.split("`")
    if len(parts) % 2 == 0:  # an unpaired backtick: left as it is
        return out
    return "".join(p if i % 2 == 0 else rf"\texttt{{{p}}}" for i, p in enumerate(parts))


Figures = dict[str, list[tuple[float, float, float] | None]]


def _over_seeds(report: Report, cell, column: str) -> tuple[float, float, float] | None:
    """A model's RMSE at one budget over its seeds (:func:`.seedstats.hierarchical_bootstrap`)."""
    from .seedstats import hierarchical_bootstrap

    if any(report.values(e, f"rmse/{column}") is None for e in cell.rows.values()):
        return None
    return hierarchical_bootstrap(cell.matrix(report, f"rmse/{column}"))


def _figures(report: Report) -> tuple[Figures, int]:
    """Row name -> its RMSE ``(mean, low, high)`` per column (None where the row lacks it), and how
    many rows stand before the baselines. With several seeds or budgets per model
    (:func:`~svbrdf_bench.report.seedstats.shown`) each model and budget is one row over its seeds;
    reference and refined rows, then the baselines, follow as they are."""
    from .seedstats import cells, shown

    out: Figures = {}
    alone: list[ModelEntry] = [e for e in report.models if not e.baseline]
    if shown(report):
        for cell in cells(report):
            seeds = f" ({len(cell.rows)} seeds)" if len(cell.rows) > 1 else ""
            out[cell.name + seeds] = [_over_seeds(report, cell, c) for c in COLUMNS]
        grouped = {id(e) for e in report.competitors}
        alone = [e for e in alone if id(e) not in grouped]
    out |= {e.name: [report.interval(e, "rmse", c) for c in COLUMNS] for e in alone}
    before = len(out)
    out |= {e.name: [report.interval(e, "rmse", c) for c in COLUMNS] for e in report.models if e.baseline}
    return out, before


def seed_count(report: Report) -> int | None:
    """The most seeds of any model (``--seeds N``); None with one seed each."""
    from .seedstats import cells

    most = max((len(c.rows) for c in cells(report)), default=1)
    return most if most > 1 else None


def _best(figures: dict[str, list]) -> list[float | None]:
    """Per column, the lowest mean as printed (None: no row has the column)."""
    out = []
    for i in range(len(COLUMNS)):
        means = [round(cells[i][0], DIGITS) for cells in figures.values() if cells[i] is not None]
        out.append(min(means) if means else None)
    return out


def caption(report: Report, seeds: int | None = None) -> str:
    """The caption: what the figures are, on which test set, over how many materials and seeds,
    under which protocol, and which rows are baselines (`code spans` for names)."""
    units, strips = unit_count(report)
    over = (
        f"{units} materials ({strips} strips; a Des18 strip counts for both its materials)"
        if report.per_material_on and report.group_by == "des18"
        else f"{units} materials ({strips} files)"
        if report.per_material_on
        else f"{units} test images, each its own material"
    )
    unit = "materials" if report.per_material_on else "images"
    what = {e.label: PURE_OPTIMISATION if e.pure_optimisation else BASELINE_WORDS.get(e.label, "untrained")
            for e in report.models if e.baseline}  # fmt: skip
    baselines = "; ".join(f"`{label}`: {words}" for label, words in what.items())
    seeds_words = (
        f", {seeds} seeds per model (a model's figure: the mean over its seeds; its interval: a "
        f"bootstrap over seeds, then {unit})"
        if seeds
        else ""
    )
    return (
        f"RMSE (lower is better) on {report.test_set}: {over}{seeds_words}"
        + f". Maps on their stored encodings in [0, 1] (normal as (n+1)/2); render: 6 fixed light/view "
        f"pairs, clipped and sRGB-encoded. Each figure is the mean over {unit}"
        + (" of the per-material means" if report.per_material_on else "")
        + f", with its 95% percentile-bootstrap interval over {unit}; best per column in bold. "
        + (f"Untrained baselines: {baselines}. " if baselines else "")
        + export_words(report)
        + f"Training: {report.minutes} ({report.preset} preset). svbrdf-bench parent run {report.parent_id}."
    )


def _cell(ci: tuple[float, float, float] | None, best: float | None, bold: str) -> tuple[str, str]:
    """``(figure, interval)`` as text; the figure wrapped in ``bold`` (a format) when it is the best."""
    if ci is None:
        return "-", ""
    figure = f"{ci[0]:.{DIGITS}f}"
    if best is not None and round(ci[0], DIGITS) == best:
        figure = bold.format(figure)
    return figure, f"[{ci[1]:.{DIGITS}f}, {ci[2]:.{DIGITS}f}]"


def _copied(rows: dict[str, list[float | None]]) -> list[tuple[str, list[str]]]:
    """Rows scored outside this table's protocol (:func:`export_rescored`, :func:`export_rows`):
    their label and each RMSE, ``-`` where there is none; no interval and never in bold."""
    return [(name, ["-" if v is None else f"{v:.{DIGITS}f}" for v in values])
            for name, values in rows.items()]  # fmt: skip


def _markdown(report: Report, seeds: int | None) -> str:
    figures, _ = _figures(report)
    best = _best(figures)
    lines = [f"**Table.** {caption(report, seeds)}", "", "| model | " + " | ".join(COLUMNS) + " |",
             "| :--- | " + " | ".join("---:" for _ in COLUMNS) + " |"]  # fmt: skip
    rows = [(name, [" ".join(_cell(ci, b, "**{}**")).strip() for ci, b in zip(cells, best, strict=True)])
            for name, cells in figures.items()]  # fmt: skip
    for name, shown in [*rows, *_copied(export_rescored(report)), *_copied(export_rows(report))]:
        name = name.replace("|", "\\|")  # a bar would end the cell
        lines.append(f"| {name} | " + " | ".join(shown) + " |")
    return "\n".join(lines) + "\n"


def _latex(report: Report, seeds: int | None) -> str:
    figures, before = _figures(report)
    best = _best(figures)
    body = []
    for i, (name, cells) in enumerate(figures.items()):
        if i == before and 0 < i < len(figures):
            body.append(r"\midrule")  # the baselines apart
        shown = []
        for ci, b in zip(cells, best, strict=True):
            figure, interval = _cell(ci, b, r"\textbf{{{}}}")
            shown.append(f"{figure} {{\\scriptsize {interval}}}" if interval else figure)
        body.append(f"{latex_escape(name)} & " + " & ".join(shown) + r" \\")
    # apart from the rows scored here: this run's rows scored as published, then the copied rows
    for apart in (_copied(export_rescored(report)), _copied(export_rows(report))):
        body += [r"\midrule"] * bool(apart)
        body += [f"{latex_escape(name)} & " + " & ".join(cells) + r" \\" for name, cells in apart]
    head = "Model & " + " & ".join(c.capitalize() for c in COLUMNS) + r" \\"
    return "\n".join([
        f"% svbrdf-bench export {report.parent_id} --format latex; needs \\usepackage{{booktabs}}",
        r"\begin{table}[t]", r"\centering", rf"\caption{{{latex_escape(caption(report, seeds))}}}",
        r"\label{tab:svbrdf-bench-rmse}", r"\begin{tabular}{l" + "c" * len(COLUMNS) + "}", r"\toprule",
        head, r"\midrule", *body, r"\bottomrule", r"\end{tabular}", r"\end{table}", "",
    ])  # fmt: skip


def check_format(fmt: str) -> str:
    """``fmt`` when it is one of :data:`EXPORT_FORMATS`; else the one-line error."""
    from ..errors import BenchError

    if fmt not in EXPORT_FORMATS:
        raise BenchError(f"unknown export format {fmt!r}: choose one of {', '.join(EXPORT_FORMATS)}")
    return fmt


def export_table(report: Report, fmt: str) -> str:
    """The RMSE table of ``report`` in ``fmt`` (``latex`` or ``markdown``)."""
    seeds = seed_count(report)
    return _latex(report, seeds) if check_format(fmt) == "latex" else _markdown(report, seeds)
