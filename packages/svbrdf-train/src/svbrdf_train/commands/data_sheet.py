"""``svbrdf-train data sheet``: a contact sheet of procedural samples, to judge their variety."""

from __future__ import annotations

import sys
from pathlib import Path

import click
import torch

from .data_shards import _interruptible
from .options import SEED, FiniteFloatRange, threads_option

__all__ = ["COMMANDS", "sheet"]

_EPILOG = """\b
Examples:
  svbrdf-train data sheet -o sheet.png                        # 8 samples of seed 0
  svbrdf-train data sheet -n 12 --seed 3 -o sheet.png         # another 12
  svbrdf-train data sheet --family tiles --family wood -o tw.png
  svbrdf-train data sheet --mix 1 --resolution 128 -o mixes.png

\b
Each row is one sample of `svbrdf-train data make` with the same seed: its simulated
phone photo, then normal, diffuse, roughness and specular maps. Photos and albedos are
shown sRGB-encoded (they are stored linear); normals as (n + 1) / 2.
"""


def _families(ctx, param, value):
    from ..data.procedural import FAMILIES

    unknown = [v for v in value if v not in FAMILIES]
    if unknown:
        raise click.BadParameter(
            f"unknown famil{'y' if len(unknown) == 1 else 'ies'} {', '.join(repr(u) for u in unknown)}; "
            f"choose from {', '.join(FAMILIES)}"
        )
    return tuple(value) or None


@click.command("sheet", epilog=_EPILOG)
@click.option(
    "-n",
    "--count",
    default=8,
    show_default=True,
    type=click.IntRange(1, 256),
    help="Number of samples (rows).",
)
@click.option(
    "-r",
    "--resolution",
    default=256,
    show_default=True,
    type=click.IntRange(8, 2048),
    help="Size of every tile in pixels.",
)
@click.option(
    "--seed", default=0, show_default=True, type=SEED, help="Data set seed (as in `data make`)."
)
@click.option(
    "--start", default=0, show_default=True, type=click.IntRange(0), help="Index of the first sample shown."
)
@click.option(
    "--family",
    "families",
    multiple=True,
    callback=_families,
    metavar="NAME",
    help="Draw only from this family; repeat for several (default: all of stone, tiles, "
    "cells, wood, metal, fabric, plaster, rusted, bark, rock).",
)
@click.option(
    "--mix",
    default=0.3,
    show_default=True,
    type=FiniteFloatRange(0, 1),
    help="Probability that a sample blends two materials through a mask.",
)
@click.option(
    "-o",
    "--out",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="PNG file to write (written atomically).",
)
@threads_option()
@_interruptible
def sheet(count, resolution, seed, start, families, mix, out):
    """Write a contact sheet (PNG) of procedural samples: photo and four maps per row."""
    from svbrdf_render import write_image

    from ..data.procedural import ProceduralMaterials
    from ..data.sheet import contact_sheet

    data = ProceduralMaterials(start + count, resolution, seed, families=families, mix=mix)
    indices = list(range(start, start + count))
    parts = []
    with click.progressbar(indices, label="generating", file=sys.stderr) as bar:
        for i in bar:
            parts.append(data.batch([i]))
    batch = {key: torch.cat([p[key] for p in parts]) for key in ("input", "maps")}
    labels = [f"#{i}\n{data.family(i)}" for i in indices]
    path = write_image(out, contact_sheet(batch, labels), bits=8)
    click.echo(f"wrote {path} ({count} samples, {resolution}x{resolution}, seed {seed})")


COMMANDS = [sheet]
