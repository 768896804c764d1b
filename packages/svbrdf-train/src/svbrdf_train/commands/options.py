"""Option types the commands share: ranges that also refuse nan and inf, seeds.

click's ``FloatRange`` lets ``nan`` through (it compares false with any bound) and ``inf``
through an open upper end; these are refused here, like any value out of range, with click's
usage error (exit code 2) naming the option and the value.
"""

from __future__ import annotations

import math

import click

from ..recipe import MAX_SEED

__all__ = ["FiniteFloatRange", "SEED", "explicit", "experiment_option"]


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
