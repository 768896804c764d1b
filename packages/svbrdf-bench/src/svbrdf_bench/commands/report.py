"""``svbrdf-bench report``: rebuild a benchmark's report from MLflow."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("report")
@click.argument("parent_run_id", metavar="PARENT_RUN_ID")
@click.option(
    "-o", "--out", type=click.Path(path_type=Path, file_okay=False), help="Also write the report folder here."
)
def report(parent_run_id, out):
    """Print the tables of a finished benchmark, read back from its MLflow runs.

    \b
      svbrdf-bench report 3f2a...                # the tables
      svbrdf-bench report 3f2a... -o again/      # and report.md, CSV/JSON, plots
    """
    from ..report import build_report, terminal, write_report

    built = build_report(parent_run_id)
    click.echo(terminal(built))
    if out is not None:
        write_report(built, out)
        click.echo(f"report: {out}/report.md", err=True)


COMMANDS = [report]
