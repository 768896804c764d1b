"""``svbrdf-bench export``: a benchmark's comparison table as a paper prints it, from MLflow alone."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("export")
@click.argument("parent_run_id", metavar="PARENT_RUN_ID")
@click.option(
    "-f",
    "--format",
    "fmt",
    default="markdown",
    show_default=True,
    metavar="latex|markdown",
    help="latex: a booktabs tabular inside a table (needs \\usepackage{booktabs}); markdown: a pipe table.",
)
@click.option(
    "-o",
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write the table to this file (whole or not at all) instead of printing it.",
)
def export(parent_run_id, fmt, out):
    """The RMSE table of a finished benchmark, as a paper prints it, rebuilt from its MLflow runs.

    Rows: the models (reference and refined rows included), then the constant-map baselines
    `mean` and `photo`; columns: the RMSE of normal, diffuse, roughness, specular and of the
    renderings, each with its 95% bootstrap interval; the best of each column in bold; then the
    numbers of `run --published FILE.yaml`, marked "published, not rerun" (no interval, never
    bold). The caption names the test set, its number of materials, the seeds and the protocol.

    \b
    Examples:
      svbrdf-bench run --models ours,no-attn -o r/         # ends: "MLflow parent run 3f2a..."
      svbrdf-bench export 3f2a... --format latex -o table.tex
      svbrdf-bench export 3f2a... > table.md               # Markdown, printed
    """
    from svbrdf_render.plumbing import write_text

    from ..report import build_report
    from ..report.export import check_format, export_table

    check_format(fmt)  # before reading MLflow: a typo costs nothing
    built = build_report(parent_run_id)
    text = export_table(built, fmt)
    if out is None:
        click.echo(text, nl=False)
        return
    write_text(out, text)
    click.echo(f"export: {out}", err=True)


COMMANDS = [export]
