"""``svbrdf-bench``: compare models and show what accuracy costs in time.

Subcommands live in :mod:`svbrdf_bench.commands`; this file assembles them and turns user
errors into a one-line message (exit status 2 for bad input, 3 for a failed write).
"""

from __future__ import annotations

import sys

import click

from svbrdf_render.plumbing import EXIT_STATUS
from svbrdf_train import OneLineErrors, add_commands, run_main

from . import __version__


class _Group(OneLineErrors):
    """svbrdf-train's one-line error reporting, under this command's name."""

    prog = "svbrdf-bench"


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]}, epilog=EXIT_STATUS)
@click.version_option(__version__, message="%(prog)s %(version)s")
def cli():
    """Which model, at what cost? Train, evaluate and compare SVBRDF models.

    \b
    Start with:
      svbrdf-bench run --models ours,no-attn            # ~5 min on a 2-core CPU
      svbrdf-bench report PARENT_RUN_ID                  # rebuild a report from MLflow
      svbrdf-bench export PARENT_RUN_ID --format latex   # its RMSE table for a paper
      svbrdf-bench render                                # the renderer's accuracy against speed
    """


def _command_modules() -> list:
    """The command modules present (an installation may leave one out)."""
    import importlib

    found = []
    for name in ("run", "report", "export", "render"):
        try:
            found.append(importlib.import_module(f".commands.{name}", __package__))
        except ModuleNotFoundError as e:
            if e.name != f"{__package__}.commands.{name}":
                raise
    return found


add_commands(cli, _command_modules())


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``svbrdf-bench`` script."""
    return run_main(cli, "svbrdf-bench", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
