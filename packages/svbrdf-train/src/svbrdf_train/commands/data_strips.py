"""``svbrdf-train data strips``: map-only material strips decoded once into a strip shard, and
the folds of their materials (:mod:`svbrdf_train.data.real.strips`)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from .data_shards import _check_target, _writing
from .options import threads_option

__all__ = ["COMMANDS", "strips"]

_EPILOG = """\b
Examples:
  svbrdf-train data strips DATA/real-train --out real-train-256.h5 --tile 256
  svbrdf-train data strips DATA/real-train --folds 5          # which materials each fold holds out
  svbrdf-train fit --recipe ours-materials --size cpu --init pretrained --data real-train-256.h5

\b
FOLDER holds material strips: one PNG per material of four square tiles side by side,
normal | diffuse | roughness | specular (OpenGL normals stored as (n + 1) / 2; linear albedos;
roughness grey, alpha = r^2). There is no photo tile: training renders one for every window it
cuts. The shard holds the strips decoded (8 bits a value, one chunk per material), so a fit
reads them in a fraction of a second instead of decoding every PNG; --tile makes them smaller
(area filter, normals renormalised): 256 px is all a 128 px fit needs.

\b
--folds N lists fold k/N for k = 1..N: each material's fold is fixed by a hash of its name,
so adding a material moves no other. A recipe holds one out with data.fold (or a mix entry's
fold: k/N, or comma-separated names) and validates on it as val_fold/.
"""


def _folds(bank, n: int) -> None:
    from ..data.real.strips import fold_split

    for k in range(1, n + 1):
        try:
            _, held = fold_split(bank.names, f"{k}/{n}", bank.where)
        except Exception as e:  # an empty fold: say so in its row
            click.echo(f"fold {k}/{n}: {e}")
            continue
        click.echo(f"fold {k}/{n}: {len(held)} held out: {', '.join(held)}")


@click.command("strips", epilog=_EPILOG)
@click.argument("folder", type=click.Path(path_type=Path))
@click.option("-o", "--out", type=click.Path(path_type=Path), help="The strip shard to write (.h5).")
@click.option(
    "--tile",
    type=click.IntRange(8, 8192),
    default=None,
    help="Side of every material's tile in the shard (default: as the strips are).",
)
@click.option("--folds", type=click.IntRange(2, 100), default=None, help="List the materials of N folds.")
@click.option("--force", is_flag=True, help="Replace --out if it exists.")
@threads_option()
def strips(folder, out, tile, folds, force):
    """Check a folder of map-only material strips; write them to a strip shard (--out) or list
    their folds (--folds)."""
    from ..data.real.strip_bank import MaterialBank, resize_bank, write_strip_shard

    if out is None and folds is None:
        raise click.UsageError("give --out FILE.h5 to write a strip shard, or --folds N to list folds")
    if out is not None:
        _check_target(out, force)
    start = time.perf_counter()
    bank = MaterialBank.open(folder)  # every strip read and checked: a bad one is named here
    click.echo(f"{len(bank)} materials in {folder}, tiles of {sorted({m.shape[-1] for m in bank.maps})} px")
    if folds is not None:
        _folds(bank, folds)
    if out is None:
        return
    bank = resize_bank(bank, tile)
    with (
        _writing(out),
        click.progressbar(length=len(bank), label="writing", file=sys.stderr, width=30) as bar,
    ):
        write_strip_shard(bank, out, overwrite=force, progress=bar.update)
    size = out.stat().st_size / 2**20
    click.echo(
        f"wrote {out}: {len(bank)} materials at {bank.tile} px, {size:.1f} MiB, {time.perf_counter() - start:.1f} s"
    )


COMMANDS = [strips]
