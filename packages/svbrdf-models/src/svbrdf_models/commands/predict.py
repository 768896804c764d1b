"""``svbrdf-models predict``: maps from flash photos, with the shipped model or another one.

The predict options are declared once, here (:func:`add_options`), and run once
(:func:`run_predict`): ``svbrdf-train predict`` builds its parser from them, with its own two
model options (--checkpoint, --run) and its own default (--refine 0)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from svbrdf_render import BACKENDS, DEFAULT_REFINE_STEPS
from svbrdf_render.plumbing import MAX_THREADS, THREADS_HELP, Once, float_range, int_range

from .._registry import Registry
from ..capture.refining import DEFAULT_MAP_SIZE, FULL, METALS
from .predict_shots import run_shots

__all__ = ["MAX_MAP_SIZE", "add_options", "add_parser", "run", "run_predict"]

#: Largest --map-size: photos are refused over 50 megapixels (about 7071 px on a side).
MAX_MAP_SIZE = 8192

EPILOG_PREDICT = """\
examples:
  svbrdf-models predict photo.jpg -o maps/           # the shipped model, refined {refine} steps
  svbrdf-models predict photo.jpg -o maps/ --refine 0                 # the network's maps only
  svbrdf-models predict shots/*.png -o maps/ --linear --bits 16 --refine-seconds 20
  svbrdf-models predict big.jpg --model ours.pt -o maps/ --tiles --map-size 1024
  svbrdf-models predict IMG_0042.jpg -o maps/ --crop 600,200,1800 --map-size 512
  svbrdf-models predict IMG_1.jpg IMG_2.jpg IMG_3.jpg --shots --strip-albedo 0.8 -o maps/  # the frame

The model: --model (a file of svbrdf-train export, an https URL whose name carries its
SHA-256 prefix, models:/NAME/VERSION or runs:/ID/PATH of MLflow, pretrained[:NAME]); without
it, the model shipped inside svbrdf-models (pretrained), named on stderr; its model card says
what it was trained on and how well it does on real materials. Downloads wait at most
SVBRDF_DOWNLOAD_TIMEOUT seconds (default 30) for the server. --tiles says what it will cost
(tiles, memory) before starting, and refuses a --map-size this machine's memory cannot hold.
Training checkpoints and MLflow runs of fits: `svbrdf-train predict --checkpoint/--run`.

"""


def add_parser(sub) -> None:
    """The ``predict`` sub-command: the options of :func:`add_options`, refining by default."""
    from ..capture.batch import help_text

    p = sub.add_parser(
        "predict",
        help="maps from flash photos: network, then refinement against the photo",
        description="Capture normal, diffuse, roughness and specular maps from flash photos: the "
        "network's maps, refined against the photo at its own resolution, judged by re-rendering.",
        epilog=EPILOG_PREDICT.format(refine=DEFAULT_REFINE_STEPS) + help_text(DEFAULT_REFINE_STEPS),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(
        p,
        refine=DEFAULT_REFINE_STEPS,
        refine_note="svbrdf-train predict's is 0; Python's TrainedModel.predict refines only when "
        "asked, refine=0 by default",
    )


def add_options(p, *, refine: int, refine_note: str, sources=None):
    """Every option of ``predict``, the one declaration ``svbrdf-models predict`` and
    ``svbrdf-train predict`` share: the photos, the model and refinement here, the square and the
    files written in :func:`_add_output_options`. ``refine`` is the command's --refine default
    and ``refine_note`` what its help says of the other command's; ``sources(p)``, when given,
    adds a command's own model options after --model. Returns the group "more options"."""
    more = p.add_argument_group("more options (the ones above are what most captures need)")
    p.add_argument("photos", nargs="*", type=Path, metavar="PHOTO")  # or --calibrated DIR
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    p.add_argument(
        "--model",
        metavar="SOURCE",
        help="model file, URL, MLflow URI or pretrained[:NAME] "
        "(default: pretrained, the model shipped with svbrdf-models)",
    )
    if sources is not None:
        sources(p)
    p.add_argument(
        "--refine",
        type=int_range(0),
        default=refine,
        metavar="STEPS",
        help=f"refinement steps per photo, 0 for the network's maps only (default: {refine}; {refine_note})",
    )
    _add_metal_option(p)
    more.add_argument(
        "--reference",
        type=_reference,
        action=Once,
        metavar="X,Y,W,H:ALBEDO",
        help="a region of known albedo in the photo (pixels as displayed), such as an 18%% grey card "
        "(0.18): the diffuse albedo's level is pinned to it before refinement (one photo cannot tell "
        "a bright material from a strong flash; docs/capture-guide.md)",
    )
    more.add_argument(
        "--refine-seconds",
        type=float_range(0, above=True),
        metavar="S",
        help="about S seconds for all of a photo: its refinement gets what reading, the network and "
        "writing leave (default: no time bound)",
    )
    more.add_argument(
        "--scene",
        type=Path,
        metavar="FILE",
        help="the capture's scene (YAML) to refine under (default: a flash found per photo)",
    )
    _add_geometry_options(more)
    more.add_argument(
        "--backend",
        choices=["auto", *BACKENDS],
        default="auto",
        help="the renderer's backend for refinement (default: auto, compiled from 512x512 up, where "
        "it is faster than its compile time costs)",
    )
    _add_calibrated_options(more)
    _add_shots_options(more)
    _add_output_options(p, more)
    return more


def _add_metal_option(p) -> None:
    """``--metal auto|none``: whether the maps may say the material is a metal."""
    p.add_argument(
        "--metal",
        choices=METALS,
        default="auto",
        help="none: the material is no metal (plastic, paint, wood, stone, fabric): specular F0 0.04 "
        "grey everywhere, metallic.png 0, the refinement held to it. auto (default): the maps say "
        "where it is metal; dark glossy plastics then come out as metal: check metallic.png",
    )


def _add_geometry_options(more) -> None:
    """``--fov`` and ``--distance``: where the camera stood (:mod:`svbrdf_models.capture.geometry`)."""
    more.add_argument(
        "--fov",
        type=float,
        metavar="DEG",
        help="the lens's field of view across the photo's longer side (as displayed), in degrees, "
        "strictly between 1 and 179: for a photo whose EXIF lacks the focal length (a screenshot, an "
        "edited copy). The refinement places the camera and flash from it and the square captured "
        "(--crop included). Default: the EXIF 35 mm equivalent focal length, else the focal length "
        "and sensor; with no EXIF, 2.2 square half-widths over the photo's highlight. material.json "
        "says which (geometry)",
    )
    more.add_argument(
        "--distance",
        type=float,
        metavar="D",
        help="the camera's height over the captured square's centre, in half-widths of the square "
        "(a 20 cm square shot from 22 cm: 2.2): when you measured it, or for a lens the EXIF "
        "misdescribes. Not with --fov or --scene",
    )


def _add_calibrated_options(more) -> None:
    """``--calibrated DIR`` (instead of photos), ``--use`` and ``--holdout``."""
    more.add_argument(
        "--calibrated",
        type=Path,
        metavar="DIR",
        help="instead of photos: a calibrated set as MaterialGAN publishes its real captures (00.png, "
        "01.png, ... rectified, camera_pos.txt, light_pos.txt, image_size.txt, light_power.txt; cm): "
        "one material refined against every view used, each under its own camera and light, "
        "written to OUT/DIR-NAME/",
    )
    more.add_argument(
        "--use",
        type=_view_list,
        metavar="I,J,...",
        help="with --calibrated: the views refined against, numbered from 0 (default: all)",
    )
    more.add_argument(
        "--holdout",
        action="store_true",
        help="with --calibrated: re-render the views not in --use under their own camera and light "
        "and report each one's relighting RMSE against its photo (material.json: holdout)",
    )


def _add_shots_options(more) -> None:
    """``--shots``, ``--strip-albedo`` and ``--flash-offset``: several shots of one material in
    the printed frame (:mod:`svbrdf_models.capture.shots`)."""
    more.add_argument(
        "--shots",
        action="store_true",
        help="the photos are handheld flash shots of ONE material in the printed frame (svbrdf-models "
        "frame): each one's camera and flash placed by its markers (the focal length from the EXIF, or "
        "--fov), one material refined against all of them, written to OUT/FIRST-STEM/",
    )
    more.add_argument(
        "--strip-albedo",
        type=float_range(0.01, 1),
        metavar="A",
        help="with --shots: the albedo of the frame's paper (plain printer paper about 0.8): each shot's "
        "flash is read off the frame's reference strip (default: the shots' exposures relative to "
        "each other, the level from the network)",
    )
    more.add_argument(
        "--flash-offset",
        type=_offset,
        metavar="DX,DY",
        help="with --shots: the flash's place beside the lens in cm, right and up as the photo is "
        "shown (default: 1,0; measure your phone's)",
    )


def _offset(text: str) -> tuple[float, float]:
    try:
        dx, dy = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DX,DY (two numbers in cm), got {text!r}") from None
    if not all(abs(v) <= 10 for v in (dx, dy)):
        raise argparse.ArgumentTypeError(f"the flash is within 10 cm of the lens, got {text!r}")
    return dx, dy


def _view_list(text: str) -> list[int]:
    try:
        views = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected view numbers I,J,... (from 0), got {text!r}") from None
    if any(v < 0 for v in views):
        raise argparse.ArgumentTypeError(f"view numbers start at 0, got {text!r}")
    return views


def _add_output_options(p, more) -> None:
    """``predict``'s options for the square read and the maps and figures written: ``--crop``
    and ``--map-size`` on ``p`` (what most captures need), the rest in the group ``more``."""
    from ..capture.one import ALBEDO_ENCODINGS, RELIT_FORMATS

    more.add_argument(
        "--linear",
        action="store_true",
        help="research use, Des18's convention: the photos hold linear values (default: sRGB) and "
        "diffuse.png/specular.png are written linear (unless --albedo-encoding srgb)",
    )
    p.add_argument(
        "--crop",
        metavar="X,Y,SIZE",
        type=_crop,
        help="the square to capture, in pixels of the photo as displayed (default: centred)",
    )
    more.add_argument(
        "--tiles", action="store_true", help="predict at high resolution from overlapping tiles"
    )
    p.add_argument(
        "--map-size",
        type=_map_size,
        metavar="N|full",
        help="with --tiles or --refine: side of the maps, or full for the square's own (default: "
        f"the square's own with --tiles; refined maps at most {DEFAULT_MAP_SIZE} px, which "
        "bounds memory and time: a refinement holds about 1.4 KB a pixel)",
    )
    more.add_argument(
        "--normal",
        "--normal-convention",
        dest="normal_convention",
        type=_normal_convention,
        default="opengl",
        metavar="{opengl,directx,gl,dx}",
        help="normal.png's convention: directx (dx) stores the normal's y (green) flipped, as "
        "Unreal and 3ds Max expect (default: opengl, as Blender, Substance, glTF expect)",
    )
    more.add_argument("--bits", type=int, choices=[8, 16], default=8, help="PNG bit depth (default: 8)")
    more.add_argument(
        "--albedo-encoding",
        choices=ALBEDO_ENCODINGS,
        help="how diffuse.png and specular.png store values (default: srgb, as texture tools expect; "
        "linear with --linear). basecolor.png is sRGB whatever this says",
    )
    more.add_argument(
        "--exr", action="store_true", help="also write the maps as OpenEXR (linear half floats)"
    )
    more.add_argument(
        "--tileable",
        action="store_true",
        help="make the maps' opposite edges match, for materials that repeat (a band at the edges "
        "is blended; material.json gives the seam error before and after)",
    )
    more.add_argument("--relit", choices=RELIT_FORMATS, default="gif", help="relit preview (default: gif)")
    more.add_argument("--device", default="cpu", help="cpu, cuda, cuda:K or auto (default: cpu)")
    more.add_argument("--threads", type=int_range(1, MAX_THREADS), metavar="N", help=THREADS_HELP)


def _reference(text: str):
    from ..capture.reference import Reference
    from ..errors import DataError

    try:
        return Reference.parse(text)
    except DataError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix(f"--reference {text!r}: ")) from None


def _map_size(text: str) -> int | str:
    if text.strip().lower() == FULL:
        return FULL
    return int_range(1, MAX_MAP_SIZE)(text)


def _normal_convention(text: str) -> str:
    from ..capture.one import NORMAL_ALIASES, NORMAL_CONVENTIONS

    convention = NORMAL_ALIASES.get(text.lower(), text.lower())
    if convention not in NORMAL_CONVENTIONS:
        raise argparse.ArgumentTypeError(f"expected opengl (gl) or directx (dx), got {text!r}")
    return convention


def _crop(text: str) -> tuple[int, int, int]:
    try:
        x, y, size = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected X,Y,SIZE (three integers in pixels), got {text!r}"
        ) from None
    if x < 0 or y < 0 or size <= 0:
        raise argparse.ArgumentTypeError(f"X and Y must be >= 0 and SIZE > 0, got {text!r}")
    return x, y, size


def run(args, registry: Registry, out) -> int:
    """``svbrdf-models predict``: :func:`run_predict` with the model of --model."""
    return run_predict(args, _load_predict_model, prog="svbrdf-models")


def run_predict(args, load, *, prog: str) -> int:
    """A parsed ``predict`` (the options of :func:`add_options`): the options checked, the model
    loaded and announced, the photos captured; the batch's exit status. ``load(args, device)``
    gives the model and the line naming it; ``prog`` starts the messages."""
    from svbrdf_render.plumbing import check_output_folder, pick_device

    from ..capture.batch import announce_model, capture_batch, check_material_folders, set_threads

    calibrated = _calibrated(args)  # photos, or a calibrated set: one of them
    options = _capture_options(args)
    if calibrated:
        return _run_calibrated(args, options, load, prog)
    if args.shots:
        return run_shots(args, options, load, prog)
    device = pick_device(args.device)  # a GPU that is not there is named as such
    check_output_folder(args.out, "-o")  # before the model is loaded and the first photo is done
    check_material_folders(args.photos, args.out)
    if args.tiles and isinstance(args.map_size, int):  # refused before the model loads
        from ..capture.tiles import check_tiled_memory

        check_tiled_memory(args.map_size, f"--tiles --map-size {args.map_size}")
    model, line = load(args, device)
    announce_model(model, line, args.map_size if args.tiles and args.map_size != FULL else None)
    set_threads(args.threads)  # after every refusal, so that a refusal stays one line
    summary = {"model": model.source, "step": model.steps, "resolution": model.resolution,
               "refine": args.refine, "refine_seconds": args.refine_seconds}  # fmt: skip
    return capture_batch(model, args.photos, args.out, options, prog=prog, summary=summary)


def _capture_options(args):
    """The :class:`~svbrdf_models.capture.one.CaptureOptions` of ``predict``'s flags: flags that go
    with another one given alone are refused there (the one place that rule is written), and the
    --scene file is read there once they agree."""
    from ..capture.one import CaptureOptions

    return CaptureOptions(
        linear=args.linear,
        crop=args.crop,
        tiles=args.tiles,
        map_size=args.map_size,
        bits=args.bits,
        normal_convention=args.normal_convention,
        relit=args.relit,
        albedo_encoding=args.albedo_encoding or ("linear" if args.linear else "srgb"),
        exr=args.exr,
        tileable=args.tileable,
        refine=args.refine,
        refine_seconds=args.refine_seconds,
        scene=args.scene,
        reference=args.reference,
        backend=args.backend,
        fov=args.fov,
        distance=args.distance,
        metal=args.metal,
    )


def _load_predict_model(args, device):
    """The model of --model (the shipped one when None, said on stderr) and the line naming it."""
    from ..modelfile.files import PRETRAINED, card_path, load_model

    if args.model is None:
        print(
            f"no --model: using the model shipped with svbrdf-models (pretrained:{PRETRAINED}; "
            f"its card: {card_path()})",
            file=sys.stderr,
        )
    model = load_model(args.model or "pretrained", device)
    return model, model.describe()


def _calibrated(args) -> bool:
    """Whether ``args`` capture a calibrated set (--calibrated) rather than photos; photos and
    --calibrated together, neither, or --use and --holdout without --calibrated (and the options
    of --shots without it) are refused."""
    from ..errors import DataError

    shots = [f for f, v in (("--strip-albedo", args.strip_albedo), ("--flash-offset", args.flash_offset))
             if v is not None]  # fmt: skip
    if shots and not args.shots:
        raise DataError(f"{shots[0]} goes with --shots")
    if args.shots and args.calibrated is not None:
        raise DataError("--shots and --calibrated DIR: give the shots' photos or a calibrated set, not both")
    if args.calibrated is None:
        alone = [f for f, v in (("--use", args.use is not None), ("--holdout", args.holdout)) if v]
        if alone:
            raise DataError(f"{alone[0]} goes with --calibrated DIR")
        if not args.photos:
            raise DataError("no photos: give the photos to capture (PHOTO ...) or --calibrated DIR")
        return False
    if args.photos:
        raise DataError("give photos or --calibrated DIR, not both")
    return True


def _run_calibrated(args, options, load, prog: str) -> int:
    """``predict --calibrated DIR``: the set checked before the model loads, captured into
    OUT/DIR-NAME/ (:func:`svbrdf_models.capture.calibrated.capture_calibrated`); the folder and
    the held-out views' relighting RMSEs printed."""
    from svbrdf_render.plumbing import ProgressBar, check_output_folder, pick_device

    from ..capture.batch import announce_model, set_threads
    from ..capture.calibrated import capture_calibrated, check_options, check_views, read_calibrated
    from ..capture.material import check_material_folder

    device = pick_device(args.device)
    check_output_folder(args.out, "-o")
    check_options(options)
    calibrated = read_calibrated(args.calibrated, linear=options.linear)
    check_views(args.use, len(calibrated[0].files), args.holdout)
    folder = args.out / calibrated[0].folder.resolve().name
    check_material_folder(folder, calibrated[0].folder, sha256=calibrated[0].sha256())
    model, line = load(args, device)
    announce_model(model, line, None)
    set_threads(args.threads)
    bar = ProgressBar(folder.name)
    try:
        record = capture_calibrated(model, calibrated, folder, options, use=args.use, holdout=args.holdout,
                                    progress=bar)  # fmt: skip
    finally:
        bar.close()
    print(str(folder), flush=True)
    held = record["holdout"]
    for name, rmse in (held or {}).get("rmse", {}).items():
        network = _number(held["rmse_network"][name])
        print(f"{prog}: holdout {name}: relighting RMSE {_number(rmse)} (network's maps {network})")
    if held:
        print(f"{prog}: holdout mean of {len(held['rmse'])} view(s): relighting RMSE {_number(held['mean'])} "
              f"(network's maps {_number(held['mean_network'])})")  # fmt: skip
    return 0


def _number(value) -> str:
    return "n/a" if value is None else f"{value:.4f}"
