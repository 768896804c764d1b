"""Option types the commands share: ranges that also refuse nan and inf, seeds.

click's ``FloatRange`` lets ``nan`` through (it compares false with any bound) and ``inf``
through an open upper end; these are refused here, like any value out of range, with click's
usage error (exit code 2) naming the option and the value.
"""

from __future__ import annotations

import math

import click

from ..recipe import MAX_SEED

__all__ = ["FiniteFloatRange", "SEED", "explicit", "experiment_option", "threads_option"]


class FiniteFloatRange(click.FloatRange):
    """``click.FloatRange`` that also refuses ``nan`` and ``inf``."""

    name = "finite float range"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return rv


#: Seeds, as recipes take them (numpy refuses negative ones; shards store them as int64).
SEED = click.IntRange(0, MAX_SEED)


def experiment_option(default: str):
    """``--experiment``: this flag, else ``MLFLOW_EXPERIMENT_NAME`` (as MLflow users set it),
    else ``default``."""
    return click.option(
        "--experiment",
        default=default,
        envvar="MLFLOW_EXPERIMENT_NAME",
        show_default=True,
        show_envvar=True,
        help="MLflow experiment (this flag, else the variable, else the default).",
    )


def explicit(ctx: click.Context, name: str) -> bool:
    """Whether option ``name`` was given on the command line (not left at its default)."""
    source = ctx.get_parameter_source(name)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


def threads_option():
    """``--threads N``: torch threads on the CPU, set as soon as the option is read (default:
    one per free core, :func:`svbrdf_render.plumbing.choose_threads`); the command never sees it."""
    from svbrdf_render.plumbing import MAX_THREADS, THREADS_HELP

    def apply(ctx, param, value):
        from svbrdf_render.plumbing import choose_threads

        choose_threads(value)

    return click.option(
        "--threads",
        type=click.IntRange(1, MAX_THREADS),
        default=None,
        expose_value=False,
        callback=apply,
        help=THREADS_HELP,
    )
