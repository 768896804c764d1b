"""``svbrdf-train predict``: capture maps a material artist can use from flash photos.

The photo tool itself lives in svbrdf-models (:mod:`svbrdf_models.capture.one`, ``svbrdf-models
predict``); this command adds the models only svbrdf-train reads: training checkpoints
(--checkpoint) and the checkpoints logged by fits in MLflow (--run).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from svbrdf_models.capture.refining import DEFAULT_MAP_SIZE, FULL
from svbrdf_render.machine import THREADS_HELP

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
  svbrdf-train predict photo.jpg --checkpoint last.pt -o maps/ --refine 150   # + refinement

\b
The model: --model (a file of svbrdf-train export, an https URL whose name carries its
SHA-256 prefix, models:/NAME/VERSION or runs:/ID/PATH of MLflow, pretrained[:NAME]),
--checkpoint (a training checkpoint or a model file) or --run (a fit's MLflow run). With
none of them, the model shipped inside svbrdf-models (pretrained) is used and named on stderr;
its model card says what it was trained on and how well it does on real materials.
The same tool without training code: svbrdf-models predict (it refines by default).

"""


def _epilog() -> str:
    from svbrdf_models.capture.batch import help_text

    return EPILOG + help_text(0, click=True)


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



class _MapSize(click.ParamType):
    """``--map-size``: a number of pixels in [1, MAX_MAP_SIZE], or ``full``."""

    name = "N|full"

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value.strip().lower() == FULL:
            return FULL
        return click.IntRange(1, MAX_MAP_SIZE).convert(value, param, ctx)

@click.command("predict", epilog=_epilog())
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
    "--linear",
    is_flag=True,
    help="Research use, Des18's convention: the photos hold linear values (default: sRGB-encoded, as "
    "cameras save) and diffuse.png/specular.png are written linear (unless --albedo-encoding srgb).",
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
    type=_MapSize(),
    metavar="N|full",
    help=f"With --tiles or --refine: side of the maps in pixels, at most {MAX_MAP_SIZE}, or full for "
    f"the square's own (default: the square's own with --tiles; refined maps at most "
    f"{DEFAULT_MAP_SIZE} px, which bounds memory and time).",
)
@click.option(
    "--normal",
    "--normal-convention",
    "normal_convention",
    type=click.Choice(["opengl", "directx", "gl", "dx"], case_sensitive=False),
    default="opengl",
    show_default=True,
    help="normal.png's convention: directx (dx) stores the normal's y (green) flipped.",
)
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="PNG bit depth.")
@click.option(
    "--albedo-encoding",
    type=click.Choice(["linear", "srgb"]),
    help="How diffuse.png and specular.png store values: srgb (default; what Blender, Substance and "
    "most texture tools expect) or linear (Des18; the default with --linear). basecolor.png is sRGB.",
)
@click.option("--exr", is_flag=True, help="Also write the maps as OpenEXR (linear half floats).")
@click.option(
    "--tileable", is_flag=True, help="Make the maps' opposite edges match, for materials that repeat."
)
@click.option(
    "--relit",
    type=click.Choice(["gif", "png", "none"]),
    default="gif",
    show_default=True,
    help="The relit preview: animated GIF, PNG grid, or none.",
)
@click.option(
    "--refine",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    metavar="STEPS",
    help="Refinement steps per photo against the photo at its own resolution (0: the network's maps "
    "only; svbrdf-models predict refines by default).",
)
@click.option(
    "--refine-seconds",
    type=click.FloatRange(min=0, min_open=True),
    metavar="S",
    help="Stop refining a photo after S seconds.",
)
@click.option(
    "--scene",
    type=click.Path(path_type=Path, dir_okay=False),
    metavar="FILE",
    help="The capture's scene (YAML) to refine under (default: a flash found per photo).",
)
@click.option(
    "--backend",
    type=click.Choice(["auto", "eager", "compiled"]),
    default="auto",
    show_default=True,
    help="The renderer's backend for refinement (auto: compiled from 512x512 up).",
)
@click.option("--device", default="cpu", show_default=True, help="cpu, cuda or cuda:K.")
@click.option("--threads", type=click.IntRange(min=1), default=None, help=THREADS_HELP)
def predict(photos, model_source, checkpoint, run_id, out, device, threads, **flags):
    """Capture normal, diffuse, roughness and specular maps from flash photos.

    The maps are judged by re-rendering them under a flash fitted to the photo: the RMSE
    against the photo is printed per photo and as the median of the batch.
    """
    from svbrdf_models.capture.batch import capture_batch, check_material_folders, pick_device, set_threads
    from svbrdf_render.formats.files import check_output_folder

    from ..errors import CheckpointError

    if sum(x is not None for x in (model_source, checkpoint, run_id)) > 1:
        raise CheckpointError("give the generator with one of --model, --checkpoint and --run, not several")
    options = _options(**flags)
    device = pick_device(device)  # a GPU that is not there is named as such, not blamed on the checkpoint
    check_output_folder(out, "-o")  # before the model is loaded and the first photo is done
    check_material_folders(photos, out)
    tile_size = options.map_size if options.tiles and options.map_size != FULL else None
    model = _load_model(model_source, checkpoint, run_id, device, tile_size)
    set_threads(threads)  # after every refusal, so that a refusal stays one line
    summary = {"model": model.source, "step": model.step, "resolution": model.resolution,
               "refine": options.refine, "refine_seconds": options.refine_seconds}  # fmt: skip
    status = capture_batch(
        model, photos, out, options, prog="svbrdf-train", summary=summary, checked=True
    )
    if status:
        sys.exit(status)


def _options(
    linear, crop, tiles, map_size, normal_convention, bits, albedo_encoding, exr, tileable, relit, refine,
    refine_seconds, scene, backend,
):  # fmt: skip
    """The :class:`~svbrdf_models.capture.one.CaptureOptions` of the flags (a flag that goes with
    another given alone is a usage error)."""
    from svbrdf_models.capture.batch import load_scene
    from svbrdf_models.capture.one import CaptureOptions

    if map_size is not None and not (tiles or refine):
        raise click.UsageError("--map-size goes with --tiles (or --refine STEPS > 0)")
    for flag, value in (("--refine-seconds", refine_seconds), ("--scene", scene)):
        if value is not None and not refine:
            raise click.UsageError(f"{flag} goes with --refine STEPS > 0")
    return CaptureOptions(
        linear,
        crop,
        tiles,
        map_size,
        int(bits),
        normal_convention.lower(),
        relit,
        albedo_encoding=albedo_encoding or ("linear" if linear else "srgb"),
        exr=exr,
        tileable=tileable,
        refine=refine,
        refine_seconds=refine_seconds,
        scene=None if scene is None else load_scene(scene),
        backend=backend,
    )


def _load_model(model_source, checkpoint, run_id, device, tile_size):
    """The :class:`~svbrdf_train.predict.Predictor` of --model, --checkpoint or --run (the shipped
    model when none is given), announced on stderr."""
    from ..predict import Predictor

    if checkpoint is not None:
        model = Predictor.from_checkpoint(checkpoint, device)
    elif run_id is not None:
        from ..training.checkpoint import check_run_kept

        hint = f"restore it (mlflow runs restore --run-id {run_id}) or give another run"
        check_run_kept(run_id, "--run", hint)
        model = Predictor.from_run(run_id, device)
    else:
        if model_source is None:
            from svbrdf_models.modelfile.files import PRETRAINED, card_path

            click.echo(
                f"no --model, --checkpoint or --run: using the model shipped with svbrdf-models "
                f"(pretrained:{PRETRAINED}; its card: {card_path()})",
                err=True,
            )
        model = Predictor.from_model(model_source or "pretrained", device)
    if tile_size is not None and tile_size < model.resolution:
        raise click.BadParameter(
            f"{tile_size} is smaller than the model's resolution ({model.resolution})",
            param_hint="--map-size",
        )
    click.echo(
        model.card
        or f"generator {model.name} from {model.source} (step {model.step}), "
        f"{model.resolution}x{model.resolution}",
        err=True,
    )
    return model


COMMANDS = [predict]
