"""``svbrdf-train data make | import | info``: write HDF5 shards and look inside them.

The shard layout is described in :mod:`svbrdf_train.data.shards`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import sys
import time
from pathlib import Path

import click

from svbrdf_models.errors import DataError
from svbrdf_render.plumbing import raise_if_interrupted

from ..recipe.datasection import CAPTURES
from .options import SEED, FiniteFloatRange, explicit, threads_option

#: Largest side of a shard's samples: one 4096 px sample already takes about 1 GB in memory.
MAX_SHARD_RESOLUTION = 4096

EPILOG_MAKE = """\b
Examples:
  svbrdf-train data make --count 10000 --resolution 256 --out train.h5
  svbrdf-train data make -n 2000 -r 256 --seed 1 --out train-1.h5   # another shard, other samples
  svbrdf-train data make -n 500 --family wood --family metal --bits 16 --out wood-metal.h5

\b
Sample i of seed s is the same in every run, process and worker (procedural:s:i), so
shards made with different seeds hold different samples, and a shard can be made again from
its attributes (generator_version, seed, resolution, families: see `data info`). Across
CPUs, the bytes match where torch uses the same SIMD kernels (AVX2 and AVX512 do).
The file appears under --out only when complete.
"""

EPILOG_IMPORT = """\b
Examples:
  svbrdf-train data import DATA/des18-dev --out des18-dev.h5
  svbrdf-train data import Deschaintre2018 --split test --out test.h5     # reads testBlended/
  svbrdf-train data import Deschaintre2018 --split train --full --out train-full.h5

\b
DIR is a folder of Des18 strips (five tiles: input | normal | diffuse | roughness |
specular) or a folder holding trainBlended/ and testBlended/ (--split picks one). Each
strip becomes one sample: its centre --crop (256 by default, the evaluation crop) or,
with --full, the whole tile. A sample's name is its file name.
"""

EPILOG_INFO = """\b
Examples:
  svbrdf-train data info train.h5
  svbrdf-train data info --check train-*.h5     # also decode every sample

\b
Without --check only the attributes and dataset shapes are checked (instant); --check
reads every sample and names the first one that is damaged.
"""


def _stderr_progress(length: int, label: str):
    return click.progressbar(length=length, label=label, file=sys.stderr, width=30)


@contextlib.contextmanager
def _writing(out: Path):
    """Ctrl-C and SIGTERM alike: the shard's temporary file is removed and ``out`` is left as it
    was, one line says so, and the exit status is 130 (click alone would print "Aborted!" and
    exit 1). Temporaries of ``out`` left by earlier runs killed outright are removed first."""
    from svbrdf_render.plumbing import INTERRUPTED, remove_stale_temporaries, sigterm_as_interrupt

    remove_stale_temporaries(out.parent, (out.name,))
    try:
        with sigterm_as_interrupt():
            yield
    except KeyboardInterrupt:
        click.echo(f"\nsvbrdf-train: interrupted: {out} not written (left as it was)", err=True)
        sys.exit(INTERRUPTED)


def _interruptible(command):
    """Run a shard-writing command (its ``out`` argument) inside :func:`_writing`."""

    @functools.wraps(command)
    def run(*args, **kwargs):
        with _writing(kwargs["out"]):
            return command(*args, **kwargs)

    return run


def _check_target(out: Path, force: bool) -> None:
    if out.exists() and not force:
        raise DataError(f"{out}: already exists; pass --force to replace it (or choose another --out)")
    if out.is_dir():
        raise DataError(f"{out}: is a folder; give the path of the .h5 file to write")


def _summary(out: Path, count: int, resolution: int, bits: int, seconds: float) -> str:
    size = out.stat().st_size
    return (
        f"wrote {out}: {count} samples at {resolution}x{resolution}, {bits}-bit, "
        f"{size / 2**20:.1f} MiB ({size / count / 2**10:.0f} KiB per sample), "
        f"{count / seconds:.1f} samples/s"
    )


@click.command("make", epilog=EPILOG_MAKE)
@click.option("-n", "--count", type=click.IntRange(min=1), required=True, help="Number of samples.")
@click.option(
    "-r",
    "--resolution",
    type=click.IntRange(8, MAX_SHARD_RESOLUTION),
    default=256,
    show_default=True,
    help=f"Side in pixels (8 to {MAX_SHARD_RESOLUTION}).",
)
@click.option(
    "-o", "--out", type=click.Path(path_type=Path), required=True, help="The shard to write (.h5)."
)
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the samples.")
@click.option(
    "--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="Bits per stored value."
)
@click.option(
    "--batch",
    type=click.IntRange(1, 1024),
    default=16,
    show_default=True,
    help="Samples generated at once (1 to 1024).",
)
@click.option(
    "--family",
    "families",
    multiple=True,
    metavar="NAME",
    help="Only this material family; repeat for several (default: all). A wrong name lists them.",
)
@click.option(
    "--mix",
    type=FiniteFloatRange(0, 1),
    default=None,
    help="Fraction of samples mixing two families through a mask (default: the generator's).",
)
@click.option(
    "--capture",
    type=click.Choice(CAPTURES),
    default="des18",
    show_default=True,
    help="How the photos are taken: des18 (the Des18 inputs' flash), phone (flashes fitted to "
    "real phone photos, white balance, JPEG) or handheld (phone plus the LED beside the lens, "
    "its beam, the camera off-centre, vignetting, a tone curve); recorded with the photo settings.",
)
@click.option("--force", is_flag=True, help="Replace --out if it exists.")
@threads_option()
@_interruptible
def make(count, resolution, out, seed, bits, batch, families, mix, capture, force):
    """Make a shard of procedural materials with their simulated flash photos.

    No download: each sample is generated from (--seed, index), rendered under a jittered
    phone flash, and stored with its four maps.
    """
    from ..data.procedural import GENERATOR_VERSION, ProceduralMaterials
    from ..data.shards import ShardWriter
    from ..data.simulated_photo import PhotoSettings

    bits = int(bits)
    kwargs = {} if mix is None else {"mix": mix}
    # Unknown families are refused here, before --out is looked at.
    photo = PhotoSettings.preset(capture)
    materials = ProceduralMaterials(
        count, resolution, seed, families=list(families) or None, photo=photo, **kwargs
    )
    _check_target(out, force)
    attrs = {
        "source": "procedural",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "families": list(materials.families),
        "mix": materials.mix,
        "capture": capture,
        "photo": dataclasses.asdict(materials.photo),
    }
    start = time.perf_counter()
    with ShardWriter(out, resolution, bits=bits, attrs=attrs, overwrite=force) as shard:
        with _stderr_progress(count, f"making {out.name}") as bar:
            for first in range(0, count, batch):
                indices = list(range(first, min(first + batch, count)))
                shard.extend(materials.batch(indices))
                bar.update(len(indices))
                raise_if_interrupted()  # a signal whose interrupt Python dropped
    click.echo(_summary(out, count, resolution, bits, time.perf_counter() - start))


@click.command("import", epilog=EPILOG_IMPORT)
@click.argument("folder", metavar="DIR", type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", type=click.Path(path_type=Path), required=True, help="The shard to write (.h5)."
)
@click.option(
    "--split",
    type=click.Choice(["test", "train"]),
    default="test",
    show_default=True,
    help="Subfolder testBlended/ or trainBlended/ when DIR has them.",
)
@click.option(
    "--crop",
    type=click.IntRange(8, MAX_SHARD_RESOLUTION),
    default=256,
    show_default=True,
    help="Side of the centre crop (not with --full).",
)
@click.option("--full", is_flag=True, help="Keep whole tiles instead of the centre crop.")
@click.option(
    "--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="Bits per stored value."
)
@click.option("--force", is_flag=True, help="Replace --out if it exists.")
@threads_option()
@click.pass_context
@_interruptible
def import_(ctx, folder, out, split, crop, full, bits, force):
    """Import a Des18 folder (strips with ground truth) into a shard."""
    if full and explicit(ctx, "crop"):
        raise click.UsageError(f"--crop {crop} and --full: --full keeps whole tiles, give one of them")
    from ..data.real.des18 import Des18Folder
    from ..data.shards import ShardWriter

    bits = int(bits)
    strips = Des18Folder(folder, split=split, crop=None if full else crop, augment=False, random_crop=False)
    _check_target(out, force)
    first = strips[0]  # also fixes the resolution of a --full import
    resolution = first["input"].shape[-1]
    attrs = {
        "source": "des18",
        "source_folder": str(strips.folder.resolve()),
        "split": split,
        "crop": "full tile" if full else f"centre {crop}",
    }
    start = time.perf_counter()
    with ShardWriter(out, resolution, bits=bits, attrs=attrs, overwrite=force) as shard:
        with _stderr_progress(len(strips), f"importing {strips.folder.name}") as bar:
            shard.append(first)
            bar.update(1)
            for i in range(1, len(strips)):
                shard.append(strips[i])
                bar.update(1)
                raise_if_interrupted()
    click.echo(_summary(out, len(strips), resolution, bits, time.perf_counter() - start))


def _format_attr(value) -> str:
    if isinstance(value, list):
        return ", ".join(str(v) for v in value)
    if isinstance(value, str) and value.startswith("{"):
        try:
            return json.dumps(json.loads(value), sort_keys=True)
        except ValueError:
            return value
    return str(value)


#: Provenance first, in the order a person asks about it; other attributes follow by name.
_INFO_ORDER = (
    "source", "generator_version", "seed", "families", "mix", "capture", "photo",
    "source_folder", "split", "crop",
)


def _info_rank(key: str) -> tuple[int, str]:
    return (_INFO_ORDER.index(key) if key in _INFO_ORDER else len(_INFO_ORDER), key)


@click.command("info", epilog=EPILOG_INFO)
@click.argument("files", metavar="FILE...", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--check", is_flag=True, help="Decode every sample (finds damaged data).")
def info(files, check):
    """Print what shards hold: samples, resolution, depth, provenance."""
    from ..data.shards import ShardDataset, inspect_shard

    shown = {"format", "format_version", "count", "resolution", "bits", "complete"}
    for path in files:
        shard = inspect_shard(path)
        size = path.stat().st_size
        per = f" ({size / shard.count / 2**10:.0f} KiB per sample)" if shard.count else ""
        rows = [
            (
                "samples",
                f"{shard.count} at {shard.resolution}x{shard.resolution}, {shard.bits}-bit "
                f"(format {shard.attrs['format_version']}, complete)",
            ),
            ("file size", f"{size / 2**20:.1f} MiB{per}"),
        ]
        rest = sorted(set(shard.attrs) - shown, key=_info_rank)
        rows += [(key, _format_attr(shard.attrs[key])) for key in rest]
        width = max(len(key) for key, _ in rows)
        click.echo(f"{path}")
        for key, value in rows:
            click.echo(f"  {key:<{width}}  {value}")
        if check:
            data = ShardDataset(path)
            with _stderr_progress(len(data), f"checking {path.name}") as bar:
                for i in range(len(data)):
                    data[i]
                    bar.update(1)
            data.close()
            click.echo(f"  {'check':<{width}}  all {len(data)} samples decode")


COMMANDS = [make, import_, info]
