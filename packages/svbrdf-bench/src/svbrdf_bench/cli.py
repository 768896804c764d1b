"""``svbrdf-bench``: compare models and show what accuracy costs in time.

Subcommands live in :mod:`svbrdf_bench.commands`; this file assembles them and turns user
errors into a one-line message with exit code 2.
"""

from __future__ import annotations

import sys

import click

from svbrdf_render import SVBRDFError


class _Group(click.Group):
    """A click group whose commands report SVBRDFError/OSError as one line, exit code 2."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except SVBRDFError as e:
            click.echo(f"svbrdf-bench: error: {e}", err=True)
            ctx.exit(2)
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            click.echo(f"svbrdf-bench: error: {where}{e.strerror or e}", err=True)
            ctx.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="svbrdf-bench")
def cli():
    """Which model, at what cost? Train, evaluate and compare SVBRDF models.

    \b
    Start with:
      svbrdf-bench run --models ours,no-attn            # ~10 min on a 2-core CPU
      svbrdf-bench report PARENT_RUN_ID                  # rebuild a report from MLflow
      svbrdf-bench render                                # the renderer's accuracy against speed
    """


def _register() -> None:
    import importlib

    for name in ("run", "report", "render"):
        try:
            module = importlib.import_module(f".commands.{name}", __package__)
        except ModuleNotFoundError as e:
            if e.name != f"{__package__}.commands.{name}":
                raise
            continue
        for command in module.COMMANDS:
            cli.add_command(command)


_register()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``svbrdf-bench`` script."""
    try:
        cli.main(args=argv, prog_name="svbrdf-bench", standalone_mode=True)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
