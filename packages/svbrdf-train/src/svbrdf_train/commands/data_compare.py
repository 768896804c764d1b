"""``svbrdf-train data compare``: procedural materials set against real ones, statistic by statistic."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import torch

from .options import SEED, FiniteFloatRange, explicit, threads_option

__all__ = ["COMMANDS", "compare"]

_EPILOG = """\b
Examples:
  svbrdf-train data compare DATA/des18-dev
  svbrdf-train data compare DATA/des18-dev -n 256 -r 128 -o compare.png --json compare.json
  svbrdf-train data compare DATA/unseen-dev -n 256 --strips DATA/real-train --strip-share 0.5

\b
REAL_FOLDER may also hold map-only strips (normal | diffuse | roughness | specular, like
DATA/real-train): each whole tile is photographed under a fixed phone flash. --strips makes
a share of the training side real strips, cut and photographed as a fit cuts them.

\b
REAL_FOLDER holds Des18 strips (input | normal | diffuse | roughness | specular), read as
Des18Folder(REAL_FOLDER, "test", crop=R, fov="resize"): whole tiles resized to R pixels, so
both sets show the surface [-1, 1]^2 at the same resolution. Photos without ground truth
cannot be compared.

\b
Statistics, one value per material (all on linear values; luminance with Rec. 709 weights,
saturation = (max - min) / max):
  diffuse luminance, diffuse saturation   means over the diffuse albedo
  roughness mean                          mean roughness
  roughness pixels                        all roughness pixels pooled (64-bin histogram)
  specular level, specular saturation     means over the specular albedo
  slope mean, slope p90                   per-pixel tan of the normal's angle from +z
  photo mean, photo median                luminance of the linear photo
  highlight size                          share of the smoothed photo above half-way
                                          from its 1st percentile to its maximum
  highlight offset                        distance of that bright region's centroid from
                                          the centre, in patch half-widths (edge = 1)

\b
Columns: the mean and the 10th-90th percentiles of each set, and W1, the 1-D Wasserstein
(earth mover's) distance between the two sets' distributions of per-material values (for
roughness pixels: of the pooled pixel values), in the statistic's own unit: how far, on
average, the values must move to turn one distribution into the other; 0 when they agree.
"""


def _read_real(folder: Path, resolution: int, limit: int | None) -> dict:
    from torch.utils.data import default_collate

    from ..data.fitdata import Resized, open_materials

    data, _ = open_materials(folder, "data compare")  # a folder of the wrong kind fails here
    data = Resized(data, resolution)
    count = len(data) if limit is None else min(limit, len(data))
    with click.progressbar(range(count), label="reading real", file=sys.stderr, width=30) as bar:
        return default_collate([data[i] for i in bar])


def _strip_samples(path: Path, count: int, resolution: int, seed: int) -> tuple[dict, list[str]]:
    """``count`` training samples of a strip folder or shard, drawn as a fit draws them."""
    from torch.utils.data import default_collate

    from ..data.real.strip_bank import MaterialBank
    from ..data.real.strips import MaterialStrips
    from ..data.simulated_photo import PhotoSettings

    bank = MaterialBank.open(path)
    data = MaterialStrips(bank, count, resolution, seed=seed, photo=PhotoSettings.preset("phone"))
    batch = default_collate(data.__getitems__(list(range(count))))
    return batch, ["strip"] * count


def _training(count, resolution, seed, strips, share) -> tuple[dict, list[str]]:
    """The training side: procedural samples, with a ``share`` of them strips when given."""
    n_strips = round(count * share) if strips is not None else 0
    parts = []
    if count - n_strips:
        parts.append(_procedural(count - n_strips, resolution, seed))
    if n_strips:
        parts.append(_strip_samples(strips, n_strips, resolution, seed))
    batch = {key: torch.cat([p[0][key] for p in parts]) for key in ("input", "maps")}
    batch["name"] = [n for p in parts for n in p[0]["name"]]
    return batch, [f for p in parts for f in p[1]]


def _procedural(count: int, resolution: int, seed: int) -> tuple[dict, list[str]]:
    from ..data.procedural import ProceduralMaterials

    data = ProceduralMaterials(count, resolution, seed)
    parts = []
    step = 8
    with click.progressbar(range(0, count, step), label="generating", file=sys.stderr, width=30) as bar:
        for first in bar:
            parts.append(data.batch(range(first, min(first + step, count))))
    batch = {key: torch.cat([p[key] for p in parts]) for key in ("input", "maps")}
    batch["name"] = [n for p in parts for n in p["name"]]
    return batch, [data.family(i) for i in range(count)]


def _cell(s: dict[str, float]) -> str:
    return f"{s['mean']:.3f} [{s['p10']:.3f}, {s['p90']:.3f}]"


def table(rows) -> str:
    """The comparison as a Markdown table."""
    lines = [
        "| statistic | unit | procedural mean [p10, p90] | real mean [p10, p90] | W1 |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    lines += [
        f"| {r.name} | {r.unit} | {_cell(r.first)} | {_cell(r.second)} | {r.distance:.3f} |" for r in rows
    ]
    return "\n".join(lines)


def _sheet(proc: dict, families: list[str], real: dict, rows: int):
    from svbrdf_models.capture.figures import image_grid
    from svbrdf_render.formats.mapfiles import linear_to_srgb

    from ..data.sheet import COLUMNS, map_tiles

    tiles, labels = [], []
    for k in range(rows):
        left = [linear_to_srgb(proc["input"][k].float()), *map_tiles(proc["maps"][k])]
        right = [linear_to_srgb(real["input"][k].float()), *map_tiles(real["maps"][k])]
        tiles.append(left + right)
        real_id = Path(str(real["name"][k])).stem.split(";")[0]
        labels.append(f"#{k} {families[k]}\nreal {real_id}")
    columns = ["procedural", *COLUMNS[1:], "real", *COLUMNS[1:]]
    return image_grid(tiles, columns, labels, min_tile=96)


@click.command("compare", epilog=_EPILOG)
@click.argument("real_folder", type=click.Path(path_type=Path))
@click.option(
    "-n",
    "--count",
    default=64,
    show_default=True,
    type=click.IntRange(1, 4096),
    help="Number of procedural samples.",
)
@click.option(
    "-r",
    "--resolution",
    default=128,
    show_default=True,
    type=click.IntRange(8, 1024),
    help="Side in pixels of both sets (real tiles are resized whole to it).",
)
@click.option(
    "--seed", default=0, show_default=True, type=SEED, help="Procedural data set seed."
)
@click.option(
    "--real-count",
    default=None,
    type=click.IntRange(1),
    help="Read only the first this many real strips (default: all).",
)
@click.option(
    "-o",
    "--out",
    "sheet_path",
    default=None,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write a side-by-side sheet PNG: procedural samples (photo and maps) next to real ones.",
)
@click.option(
    "--rows", default=8, show_default=True, type=click.IntRange(1, 64), help="Rows of the sheet (with -o)."
)
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write the statistics (summaries, distances, per-material values) as JSON.",
)
@click.option(
    "--strips",
    type=click.Path(exists=True, path_type=Path),
    default=None,
    help="Make --strip-share of the training side real map-only strips (a folder or strip shard), "
    "drawn as a fit draws them: the training data of a mix such as ours-materials.",
)
@click.option(
    "--strip-share",
    type=FiniteFloatRange(0, 1),
    default=0.5,
    show_default=True,
    help="Share of --strips samples on the training side.",
)
@threads_option()
@click.pass_context
def compare(ctx, real_folder, count, resolution, seed, real_count, sheet_path, rows, json_path, strips, strip_share):
    """Set N procedural samples against the real materials of REAL_FOLDER: one row per
    statistic with each set's summary and the distance between them (see below)."""
    if sheet_path is None and explicit(ctx, "rows"):
        raise click.UsageError(f"--rows {rows} sets the rows of the sheet: give -o SHEET.png with it")
    from ..data.procedural import GENERATOR_VERSION
    from ..data.stats import compare as compare_sets

    if strips is None and explicit(ctx, "strip_share"):
        raise click.UsageError(f"--strip-share {strip_share} is the share of --strips: give --strips DIR with it")
    real = _read_real(real_folder, resolution, real_count)
    proc, families = _training(count, resolution, seed, strips, strip_share)
    results = compare_sets(proc, real)
    mixed = f", {strip_share:.0%} of them strips of {strips}" if strips is not None else ""
    click.echo(
        f"procedural: {count} samples of seed {seed} (generator {GENERATOR_VERSION}){mixed}; "
        f"real: {len(real['name'])} materials of {real_folder}; both {resolution}x{resolution}"
    )
    click.echo(table(results))
    click.echo("W1: 1-D Wasserstein distance between the two distributions, in the statistic's unit")
    if json_path is not None:
        doc = {
            "procedural": {
                "count": count,
                "seed": seed,
                "generator_version": GENERATOR_VERSION,
                "families": families,
            },
            "real": {"folder": str(real_folder), "count": len(real["name"]), "names": list(real["name"])},
            "resolution": resolution,
            "distance": "1-D Wasserstein distance of per-material values (roughness pixels: pooled pixels), "
            "in the statistic's unit",
            "statistics": [r.to_dict() for r in results],
        }
        from svbrdf_render.plumbing import write_text

        write_text(json_path, json.dumps(doc, indent=2) + "\n")
        click.echo(f"wrote {json_path}")
    if sheet_path is not None:
        from svbrdf_render import write_image

        n = min(rows, count, len(real["name"]))
        path = write_image(sheet_path, _sheet(proc, families, real, n), bits=8)
        click.echo(f"wrote {path} ({n} rows: procedural | real)")


COMMANDS = [compare]
