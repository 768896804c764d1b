"""``svbrdf-train``: make training data, train generators, predict maps from photos.

Subcommands live in :mod:`svbrdf_train.commands`, one module per topic; this file only
assembles them and turns user errors into a one-line message with exit code 2.
"""

from __future__ import annotations

import sys

import click

from svbrdf_render import SVBRDFError
from svbrdf_render.errors import exit_status
from svbrdf_render.plumbing import EXIT_STATUS, INTERRUPTED, sigterm_as_interrupt

from . import __version__


class OneLineErrors(click.Group):
    """A click group whose commands report SVBRDFError/OSError as one line.

    The exit status is the error's (:func:`svbrdf_render.errors.exit_status`): 2 for bad input,
    3 for a file the system refused to write. Subclass it and set ``prog`` (the command name
    the messages start with); svbrdf-bench does.
    """

    prog = "svbrdf-train"

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except SVBRDFError as e:
            click.echo(f"{self.prog}: error: {e}", err=True)
            ctx.exit(exit_status(e))
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            click.echo(f"{self.prog}: error: {where}{e.strerror or e}", err=True)
            ctx.exit(exit_status(e))
        except KeyboardInterrupt:  # Ctrl-C, or SIGTERM under run_main, where no command handles it
            click.echo(f"\n{self.prog}: interrupted", err=True)
            ctx.exit(INTERRUPTED)


def add_commands(group: click.Group, modules) -> None:
    """Add to ``group`` every command the ``modules`` list in their ``COMMANDS`` (each command
    module of svbrdf-train and svbrdf-bench ends with that list)."""
    for module in modules:
        for command in module.COMMANDS:
            group.add_command(command)


def run_main(group: click.Group, prog: str, argv: list[str] | None = None) -> int:
    """Run a click group as a console script; its exit status as an int. SIGTERM stops it as
    Ctrl-C does (exit 130), unless a command handles both itself (a fit saves first)."""
    try:
        with sigterm_as_interrupt():
            group.main(args=argv, prog_name=prog, standalone_mode=True)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    return 0


@click.group(cls=OneLineErrors, context_settings={"help_option_names": ["-h", "--help"]}, epilog=EXIT_STATUS)
@click.version_option(__version__, message="%(prog)s %(version)s")
def cli():
    """Training data and training for single-image SVBRDF recovery.

    \b
    Start with:
      svbrdf-train data sheet -o sheet.png          # look at the procedural materials
      svbrdf-train recipes                          # what can be trained
      svbrdf-train fit --recipe ours --size cpu     # train (minutes on a CPU), tracked in MLflow
      svbrdf-train predict photo.jpg --checkpoint runs/ours-cpu/last.pt -o maps/
      svbrdf-train data make --count 1000 --resolution 256 --out train.h5
      svbrdf-train data import des18-dev/ --out test.h5
      svbrdf-train data folds des18-dev/ --out folds/  # train/judge splits by source material
    """


@cli.group(cls=OneLineErrors)
def data():
    """Make, import, split and inspect training data (procedural materials, Des18, HDF5 shards)."""


def _register() -> None:
    from .commands import (
        data_compare,
        data_folds,
        data_shards,
        data_sheet,
        data_strips,
        export,
        fit,
        predict,
        recipes,
    )

    add_commands(data, (data_sheet, data_shards, data_strips, data_compare, data_folds))
    add_commands(cli, (recipes, fit, predict, export))


_register()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``svbrdf-train`` script."""
    return run_main(cli, "svbrdf-train", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
