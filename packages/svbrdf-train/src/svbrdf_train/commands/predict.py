"""``svbrdf-train predict``: capture maps a material artist can use from flash photos."""

from __future__ import annotations

import sys
from pathlib import Path

import click

#: Largest --map-size: photos are refused over 50 megapixels (about 7071 px on a side).
MAX_MAP_SIZE = 8192

EPILOG = """\b
Examples:
  svbrdf-train predict photo.jpg -o maps/                  # the model shipped with svbrdf-models
  svbrdf-train predict photo.jpg --checkpoint runs/ours-cpu/last.pt -o maps/
  svbrdf-train predict photo.jpg --model models:/svbrdf-ours/2 -o maps/
  svbrdf-train predict shots/*.png --run 3f2a... -o maps/ --linear --bits 16
  svbrdf-train predict big.jpg --checkpoint last.pt -o maps/ --tiles --map-size 1024
  svbrdf-train predict IMG_0042.jpg --checkpoint last.pt -o maps/ --crop 600,200,1800

\b
The model: --model (a file of svbrdf-train export, an https URL whose name carries its
SHA-256 prefix, models:/NAME/VERSION or runs:/ID/PATH of MLflow, pretrained[:NAME]),
--checkpoint (a training checkpoint or a model file) or --run (a fit's MLflow run). With
none of them, the model shipped inside svbrdf-models (pretrained) is used and named on stderr;
its model card says what it was trained on and how well it does on real materials.

\b
Photos: JPEG or PNG, in colour, the flash roughly at the centre. The EXIF orientation is
applied, then the largest centred square (or --crop X,Y,SIZE, in pixels of the photo as
displayed) is resized to the model's resolution and decoded from sRGB (unless --linear).
With --tiles the square is kept at its own size (or --map-size) and predicted in tiles of
the model's resolution overlapping by half, blended with raised-cosine weights; each tile
sees the flash off its centre, which the model may not have been trained for: check the
re-rendering.

\b
Each photo gets a folder DIR/NAME/:
  normal.png      tangent-space normal, stored (n+1)/2 (OpenGL y up; --normal-convention directx)
  diffuse.png     albedo, linear as Des18 stores it (--albedo-encoding srgb for texture tools)
  roughness.png   grey, alpha = roughness^2
  specular.png    albedo, encoded like diffuse.png
  input.png       the square the maps are of (sRGB)
  rerender.png    photo | re-rendering under the fitted flash | |error| heat map
  relit.gif       a point light circling the material (--relit png: a grid; none: skipped)
and DIR/summary.json holds, per photo, the status, notes, the re-rendering RMSE against the
photo (linear) and the fitted flash, and the median RMSE over the photos captured.

\b
Refused photos (each reported on its own line, the others still done): missing, folders,
not an image, neither JPEG nor PNG, under 64 px on the short side, over 50 megapixels,
grey, translucent alpha, a crop that does not fit. Processed with a note: EXIF rotation,
16-bit PNG, opaque alpha, palette or CMYK, grey saved as RGB, clipped highlights, a square
smaller than the model's resolution.

\b
stdout: the folder of each photo captured; stderr: progress, notes, errors, a summary table.
Exit status: 0 every photo captured; 1 some photos failed, others were captured; 2 every
photo failed, or bad arguments (no model, unreadable checkpoint, bad option, -o not
writable); 3 a file could not be written (disk full...): the photos after it are not done.
Every file is written whole or not at all (summary.json too).
"""


def _parse_crop(ctx, param, value):
    if value is None:
        return None
    try:
        x, y, size = (int(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected X,Y,SIZE (three integers in pixels), got {value!r}") from None
    if x < 0 or y < 0 or size <= 0:
        raise click.BadParameter(f"X and Y must be >= 0 and SIZE > 0, got {value!r}")
    return x, y, size


@click.command("predict", epilog=EPILOG)
@click.argument("photos", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--model",
    "model_source",
    metavar="SOURCE",
    help="A model file, URL, MLflow model URI (models:/NAME/VERSION, runs:/ID/PATH) or pretrained[:NAME] "
    "[default: pretrained, the model shipped with svbrdf-models].",
)
@click.option(
    "--checkpoint",
    type=click.Path(path_type=Path, dir_okay=False),
    help="A training checkpoint (last.pt, weights.pt) or a model file.",
)
@click.option(
    "--run", "run_id", metavar="RUN_ID", help="An MLflow run of svbrdf-train fit (its logged checkpoint)."
)
@click.option(
    "-o", "--out", type=click.Path(path_type=Path, file_okay=False), required=True, help="Output folder."
)
@click.option(
    "--linear", is_flag=True, help="The photos hold linear values (default: sRGB-encoded, as cameras save)."
)
@click.option(
    "--crop",
    metavar="X,Y,SIZE",
    callback=_parse_crop,
    help="The square to capture, in pixels of the photo as displayed (default: the largest centred one).",
)
@click.option("--tiles", is_flag=True, help="Predict at high resolution from overlapping tiles.")
@click.option(
    "--map-size",
    type=click.IntRange(1, MAX_MAP_SIZE),
    metavar="N",
    help=f"With --tiles: side of the maps in pixels, at most {MAX_MAP_SIZE} (default: the square's "
    "own side).",
)
@click.option(
    "--normal-convention",
    type=click.Choice(["opengl", "directx"]),
    default="opengl",
    show_default=True,
    help="directx stores the normal's y (green) flipped.",
)
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="PNG bit depth.")
@click.option(
    "--albedo-encoding",
    type=click.Choice(["linear", "srgb"]),
    default="linear",
    show_default=True,
    help="How diffuse.png and specular.png store values: linear (Des18) or srgb (base-colour "
    "inputs of Blender, Substance and most texture tools).",
)
@click.option(
    "--relit",
    type=click.Choice(["gif", "png", "none"]),
    default="gif",
    show_default=True,
    help="The relit preview: animated GIF, PNG grid, or none.",
)
@click.option("--device", default="cpu", show_default=True, help="cpu, cuda or cuda:K.")
def predict(
    photos,
    model_source,
    checkpoint,
    run_id,
    out,
    linear,
    crop,
    tiles,
    map_size,
    normal_convention,
    bits,
    albedo_encoding,
    relit,
    device,
):
    """Capture normal, diffuse, roughness and specular maps from flash photos.

    The maps are judged by re-rendering them under a flash fitted to the photo: the RMSE
    against the photo is printed per photo and as the median of the batch.
    """
    from svbrdf_render.files import check_output_folder

    from ..capture import CaptureOptions
    from ..distributed import pick_device
    from ..errors import CheckpointError

    if sum(x is not None for x in (model_source, checkpoint, run_id)) > 1:
        raise CheckpointError("give the generator with one of --model, --checkpoint and --run, not several")
    if map_size is not None and not tiles:
        raise click.UsageError("--map-size goes with --tiles")
    device = pick_device(device)  # a GPU that is not there is named as such, not blamed on the checkpoint
    options = CaptureOptions(
        linear, crop, tiles, map_size, int(bits), normal_convention, relit, albedo_encoding=albedo_encoding
    )
    check_output_folder(out, "-o")  # before the model is loaded and the first photo is done
    model = _load_model(model_source, checkpoint, run_id, device, map_size)
    entries, stopped = _capture_all(model, photos, out, options)
    _finish(model, photos, out, entries, stopped)


def _load_model(model_source, checkpoint, run_id, device, map_size):
    """The :class:`~svbrdf_train.predict.Predictor` of --model, --checkpoint or --run (the shipped
    model when none is given), announced on stderr."""
    from ..predict import Predictor

    if checkpoint is not None:
        model = Predictor.from_checkpoint(checkpoint, device)
    elif run_id is not None:
        model = Predictor.from_run(run_id, device)
    else:
        if model_source is None:
            from svbrdf_models.modelfile import PRETRAINED, card_path

            click.echo(
                f"no --model, --checkpoint or --run: using the model shipped with svbrdf-models "
                f"(pretrained:{PRETRAINED}; its card: {card_path()})",
                err=True,
            )
        model = Predictor.from_model(model_source or "pretrained", device)
    if map_size is not None and map_size < model.resolution:
        raise click.BadParameter(
            f"{map_size} is smaller than the model's resolution ({model.resolution})", param_hint="--map-size"
        )
    click.echo(
        model.card
        or f"generator {model.name} from {model.source} (step {model.step}), "
        f"{model.resolution}x{model.resolution}",
        err=True,
    )
    return model


def _capture_all(model, photos, out: Path, options):
    """Capture each photo into its own folder of ``out``; the summary entries, and the write error
    that stopped the batch (None: every photo was tried). A photo that fails is reported and
    skipped; a file that cannot be written stops the photos after it."""
    from svbrdf_render import SVBRDFError
    from svbrdf_render.errors import OutputError

    from ..capture import capture_one

    entries: list[dict] = []
    used: set[str] = set()
    for path in photos:
        name = _folder_name(path, used)
        try:
            entry = capture_one(model, path, out / name, options)
        except OutputError as e:  # the disk, not the photo: the photos after it would fail alike
            click.echo(f"svbrdf-train: error: {e}", err=True)
            entries.append({"photo": str(path), "status": "failed", "error": str(e)})
            return entries, e
        except (SVBRDFError, OSError, RuntimeError) as e:  # RuntimeError: out of memory, a broken model
            what = str(e) if isinstance(e, (SVBRDFError, OSError)) else f"{type(e).__name__}: {e}"
            text = what if what.startswith(str(path)) else f"{path}: {what}"
            click.echo(f"svbrdf-train: error: {text}", err=True)
            entries.append({"photo": str(path), "status": "failed", "error": text})
            continue
        used.add(name)
        for note in entry["notes"]:
            click.echo(f"svbrdf-train: note: {path}: {note}", err=True)
        entries.append({"name": name, **entry})
        click.echo(str(out / name))
    return entries, None


def _folder_name(path: Path, used: set[str]) -> str:
    """The photo's stem, numbered (``NAME-2``, ...) when an earlier photo of the batch took it."""
    name, k = path.stem, 1
    while name in used:
        k += 1
        name = f"{path.stem}-{k}"
    return name


def _finish(model, photos, out: Path, entries: list[dict], stopped) -> None:
    """Write summary.json, print the table and exit with the batch's status (0 when all went well)."""
    from ..capture import write_summary

    summary = write_summary(
        out / "summary.json", entries, model=model.source, step=model.step, resolution=model.resolution
    )
    click.echo(_table(entries, summary), err=True, nl=False)
    if stopped is not None:
        left = len(photos) - len(entries)
        click.echo(f"stopped: a file could not be written; {left} photo(s) after it not done", err=True)
        sys.exit(stopped.exit_code)
    failed = summary["failed"]
    if failed:
        click.echo(f"{failed} of {len(photos)} photo(s) failed", err=True)
        sys.exit(2 if failed == len(photos) else 1)


def _table(entries: list[dict], summary: dict) -> str:
    """The summary table: one line per photo, then the median."""
    names = [Path(e["photo"]).name for e in entries]
    width = max(len("photo"), *(len(n) for n in names))
    lines = [f"{'photo':<{width}}  status  {'rmse':>7}  {'flash x, y, z':>21}  {'intensity':>9}  notes"]
    for name, e in zip(names, entries, strict=True):
        if e["status"] != "ok":
            lines.append(f"{name:<{width}}  failed  {'-':>7}  {'-':>21}  {'-':>9}")
            continue
        rmse = "nan" if e["rmse"] is None else f"{e['rmse']:.4f}"
        pos = ", ".join("nan" if v is None else f"{v:+.2f}" for v in e["flash"]["position"])
        k = e["flash"]["intensity"]
        lines.append(
            f"{name:<{width}}  ok      {rmse:>7}  {pos:>21}  {'nan' if k is None else f'{k:9.3g}':>9}  "
            f"{len(e['notes'])}"
        )
    median = summary["median_rmse"]
    lines.append(
        f"median re-rendering RMSE over {summary['captured']} photo(s): "
        + ("-" if median is None else f"{median:.4f}")
    )
    return "\n".join(lines) + "\n"


COMMANDS = [predict]
