"""``svbrdf-models``: what generators, attention modules and discriminators are installed, what a
trained model file holds, and maps from flash photos (``predict``)."""

from __future__ import annotations

import argparse
import difflib
import statistics
import sys
import time
from pathlib import Path

from svbrdf_render import DEFAULT_REFINE_STEPS, SVBRDFError
from svbrdf_render.cli import OneLineParser, float_range, int_range
from svbrdf_render.errors import exit_status

from . import __version__
from ._registry import _NOUNS, KINDS, REINSTALL_HINT, Registry, default_registry
from .errors import RegistryError, UnknownNameError

#: Bounds of --channels (a 4096-channel 256x256 input is 1 GiB) and --repeats.
MAX_CHANNELS, MAX_REPEATS = 4096, 1000
DEFAULT_CHANNELS, DEFAULT_REPEATS = 64, 3
#: Largest --map-size: photos are refused over 50 megapixels (about 7071 px on a side).
MAX_MAP_SIZE = 8192

EPILOG_LIST = """\
examples:
  svbrdf-models list                         # every registered name, its package and description
  svbrdf-models list --kind attention
  svbrdf-models list --kind generator --detail              # + parameters and CPU time at 256x256
  svbrdf-models list --kind generator --detail --preset small

--detail builds each network (with --preset where it has one) and times inference on one
256x256 input on this machine's CPU: generators take a photo (1, 3, 256, 256); attention
modules a feature map (1, --channels, 256, 256); discriminators the renderings or maps of one
256x256 material. The figure is the median of --repeats runs after one warm-up.
"""

EPILOG_DESCRIBE = """\
examples:
  svbrdf-models describe ours               # config fields, defaults and presets
  svbrdf-models describe multiscale --kind attention

Fields can be set from Python (create_generator("ours", {"depth": 6})) or a recipe's YAML.
"""


EPILOG_SHOW = """\
examples:
  svbrdf-models show                        # the model shipped with svbrdf-models
  svbrdf-models show ours.pt                # a file svbrdf-train export wrote
  svbrdf-models show models:/svbrdf-ours/2  # from the MLflow model registry (needs mlflow)

Prints the generator and its config, the training resolution, steps, time, hardware and data
(with the real files it learnt), the code revision, the figures recorded with it and the
file's SHA-256. Loading checks the file fully: every field of its header (one line naming
the field otherwise), its size once unpacked, a NAME.sha256 beside it (which must match),
the network's size before it is built, and the weights (finite, fitting the generator).
A URL is downloaded once into torch.hub's cache (TORCH_HOME) and kept only when its SHA-256
matches its name and it loads; a server silent for SVBRDF_DOWNLOAD_TIMEOUT seconds (default
30) is given up on.
"""


EPILOG_PREDICT = """\
examples:
  svbrdf-models predict photo.jpg -o maps/           # the shipped model, refined {refine} steps
  svbrdf-models predict photo.jpg -o maps/ --refine 0                 # the network's maps only
  svbrdf-models predict shots/*.png -o maps/ --linear --bits 16 --refine-seconds 20
  svbrdf-models predict big.jpg --model ours.pt -o maps/ --tiles --map-size 1024
  svbrdf-models predict IMG_0042.jpg -o maps/ --crop 600,200,1800 --map-size 512

The model: --model (a file of svbrdf-train export, an https URL whose name carries its
SHA-256 prefix, models:/NAME/VERSION or runs:/ID/PATH of MLflow, pretrained[:NAME]); without
it, the model shipped inside svbrdf-models (pretrained), named on stderr; its model card says
what it was trained on and how well it does on real materials. Downloads wait at most
SVBRDF_DOWNLOAD_TIMEOUT seconds (default 30) for the server. --tiles says what it will cost
(tiles, memory) before starting, and refuses a --map-size this machine's memory cannot hold.
Training checkpoints and MLflow runs of fits: `svbrdf-train predict --checkpoint/--run`.

"""


def _add_predict(sub) -> None:
    from .batch import help_text
    from .capture import ALBEDO_ENCODINGS, RELIT_FORMATS

    p = sub.add_parser(
        "predict",
        help="maps from flash photos: network, then refinement against the photo",
        description="Capture normal, diffuse, roughness and specular maps from flash photos: the "
        "network's maps, refined against the photo at its own resolution, judged by re-rendering.",
        epilog=EPILOG_PREDICT.format(refine=DEFAULT_REFINE_STEPS) + help_text(DEFAULT_REFINE_STEPS),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("photos", nargs="+", type=Path, metavar="PHOTO")
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    p.add_argument(
        "--model",
        metavar="SOURCE",
        help="model file, URL, MLflow URI or pretrained[:NAME] "
        "(default: pretrained, the model shipped with svbrdf-models)",
    )
    p.add_argument(
        "--refine",
        type=int_range(0),
        default=DEFAULT_REFINE_STEPS,
        metavar="STEPS",
        help=f"refinement steps per photo, 0 for the network's maps only (default: {DEFAULT_REFINE_STEPS})",
    )
    p.add_argument(
        "--refine-seconds",
        type=float_range(0, above=True),
        metavar="S",
        help="stop refining a photo after S seconds (default: no time bound)",
    )
    p.add_argument(
        "--scene",
        type=Path,
        metavar="FILE",
        help="the capture's scene (YAML) to refine under (default: a flash found per photo)",
    )
    p.add_argument(
        "--backend",
        choices=["auto", "eager", "compiled"],
        default="auto",
        help="the renderer's backend for refinement (default: auto, compiled from 512x512 up, where "
        "it is faster than its compile time costs)",
    )
    p.add_argument(
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
    p.add_argument("--tiles", action="store_true", help="predict at high resolution from overlapping tiles")
    p.add_argument(
        "--map-size",
        type=int_range(1, MAX_MAP_SIZE),
        metavar="N",
        help="with --tiles or --refine: side of the maps (default: the square's own side)",
    )
    p.add_argument(
        "--normal",
        "--normal-convention",
        dest="normal_convention",
        type=_normal_convention,
        default="opengl",
        metavar="{opengl,directx,gl,dx}",
        help="normal.png's convention: directx (dx) stores the normal's y (green) flipped, as "
        "Unreal and 3ds Max expect (default: opengl, as Blender, Substance, glTF expect)",
    )
    p.add_argument("--bits", type=int, choices=[8, 16], default=8, help="PNG bit depth (default: 8)")
    p.add_argument(
        "--albedo-encoding",
        choices=ALBEDO_ENCODINGS,
        help="how diffuse.png and specular.png store values (default: srgb, as texture tools expect; "
        "linear with --linear). basecolor.png is sRGB whatever this says",
    )
    p.add_argument("--exr", action="store_true", help="also write the maps as OpenEXR (linear half floats)")
    p.add_argument(
        "--tileable",
        action="store_true",
        help="make the maps' opposite edges match, for materials that repeat (a band at the edges "
        "is blended; material.json gives the seam error before and after)",
    )
    p.add_argument("--relit", choices=RELIT_FORMATS, default="gif", help="relit preview (default: gif)")
    p.add_argument("--device", default="cpu", help="cpu, cuda, cuda:K or auto (default: cpu)")


def _normal_convention(text: str) -> str:
    from .capture import NORMAL_ALIASES, NORMAL_CONVENTIONS

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


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="svbrdf-models",
        description="List and describe the registered generators, attention modules and discriminators "
        "(built-ins and plugins, found through entry points), show what a model file holds, and "
        "capture maps from flash photos (predict).",
        epilog="Exit status: 0 done; 2 bad arguments (an unknown name, a bad option); 130 interrupted. "
        "predict: see svbrdf-models predict --help.",
    )
    parser.add_argument("--version", action="version", version=f"svbrdf-models {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "list",
        help="registered names with their source package",
        description="List registered names with their source package and description.",
        epilog=EPILOG_LIST,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--kind", choices=list(KINDS), action="append", help="only this kind (repeatable; default: all three)"
    )
    p.add_argument("--pattern", default="*", help="shell-style name filter, e.g. 'c*' (default: *)")
    p.add_argument(
        "--detail", action="store_true", help="also parameter count and CPU inference time at 256x256"
    )
    p.add_argument(
        "--preset", default=None, help="with --detail: preset to build where one exists (e.g. small)"
    )
    p.add_argument(
        "--channels",
        type=int_range(1, MAX_CHANNELS),
        default=None,
        help=f"with --detail: input channels for attention modules, 1 to {MAX_CHANNELS} "
        f"(default: {DEFAULT_CHANNELS})",
    )
    p.add_argument(
        "--repeats",
        type=int_range(1, MAX_REPEATS),
        default=None,
        help=f"with --detail: timed runs per network, 1 to {MAX_REPEATS} (default: {DEFAULT_REPEATS})",
    )

    p = sub.add_parser(
        "describe",
        help="config fields, defaults and presets of one name",
        description="Show where a registered name comes from and how to configure it.",
        epilog=EPILOG_DESCRIBE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("name")
    p.add_argument("--kind", choices=list(KINDS), help="needed only when the name exists in several kinds")

    p = sub.add_parser(
        "show",
        help="what a trained model file holds: generator, training, data, figures",
        description="Load a trained model file and say what it is and how it was made.",
        epilog=EPILOG_SHOW,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "source",
        nargs="?",
        default="pretrained",
        help="a model file, an https URL (NAME-HEX.pt), models:/NAME/VERSION, runs:/ID/PATH, or "
        "pretrained[:NAME] (default: the model shipped with this package)",
    )
    _add_predict(sub)
    return parser


def _cmd_list(args, registry: Registry, out) -> None:
    kinds = list(dict.fromkeys(args.kind or KINDS))
    _check_list_flags(args, registry, kinds)
    args.channels = args.channels or DEFAULT_CHANNELS
    args.repeats = args.repeats or DEFAULT_REPEATS
    header = f"{'kind':<14} {'name':<14} {'source':<24}"
    if args.detail:
        header += f" {'params':>10} {'CPU ms':>9}"
    print(header + "  description", file=out)
    for kind in kinds:
        for name in registry.names(kind, args.pattern):
            print(_row(registry, kind, name, args), file=out, flush=True)


def _check_list_flags(args, registry: Registry, kinds: list[str]) -> None:
    """Refuse flags that would have no effect: --detail's options without it, a --channels no
    listed kind reads, a --preset no listed network has, a --pattern that matches nothing."""
    flags = ("preset", "channels", "repeats")
    given = [f"--{n} {getattr(args, n)}" for n in flags if getattr(args, n) is not None]
    if given and not args.detail:
        raise RegistryError(f"{', '.join(given)}: only --detail builds and times networks; add --detail")
    names = {kind: registry.names(kind, args.pattern) for kind in kinds}
    if not any(names.values()):
        raise UnknownNameError(
            f"--pattern {args.pattern!r} matches no registered {' or '.join(_NOUNS[k] for k in kinds)}; "
            f"'svbrdf-models list' shows every name. {REINSTALL_HINT}"
        )
    if args.channels is not None and not names.get("attention"):
        raise RegistryError(
            f"--channels {args.channels}: only attention modules take it, and none is listed "
            "(add --kind attention)"
        )
    if args.preset is not None:
        has = set()
        for kind, listed in names.items():
            for name in listed:
                try:
                    has.update(registry.spec(kind, name).presets)
                except RegistryError:
                    continue  # listed with its error
        if args.preset not in has:
            close = difflib.get_close_matches(args.preset, sorted(has), n=2, cutoff=0.5)
            hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
            raise RegistryError(
                f"--preset {args.preset!r}: no listed network has it.{hint} "
                f"Presets: {', '.join(sorted(has)) or 'none'}."
            )


def _row(registry: Registry, kind: str, name: str, args) -> str:
    sources = registry.sources(kind, name)
    source = ", ".join(sources)
    row = f"{kind:<14} {name:<14} {source:<24}"
    try:
        spec = registry.spec(kind, name)
    except RegistryError as e:
        pad = f" {'-':>10} {'-':>9}" if args.detail else ""
        reason = "registered twice; creating it is an error" if len(sources) > 1 else f"FAILED TO LOAD: {e}"
        return f"{row}{pad}  {reason}"
    if args.detail:
        try:
            params, ms = _measure(registry, kind, name, args)
            row += f" {_count(params):>10} {ms:>9.1f}"
        except (RegistryError, RuntimeError, ValueError) as e:
            row += f" {'-':>10} {'-':>9}"
            return f"{row}  {spec.description} (could not time: {e})"
    return f"{row}  {spec.description}"


def _count(n: int) -> str:
    if n < 1000:
        return str(n)
    return f"{n / 1e3:.1f}k" if n < 1e6 else f"{n / 1e6:.2f}M"


def _measure(registry: Registry, kind: str, name: str, args) -> tuple[int, float]:
    import torch

    from svbrdf_render import SVBRDF

    spec = registry.spec(kind, name)
    config = {"preset": args.preset} if args.preset and args.preset in spec.presets else {}
    size = 256
    if kind == "attention":
        module = registry.create(kind, name, config, channels=args.channels)
        inputs = ((torch.rand(1, args.channels, size, size),), {})
    else:
        module = registry.create(kind, name, config)
        if kind == "generator":
            inputs = ((torch.rand(1, 3, size, size),), {})
        else:  # discriminators read renderings or maps: give both, sized as the config asks
            n = getattr(getattr(module, "config", None), "renderings", 9)
            inputs = ((), {"maps": SVBRDF.constant(1, size), "renderings": torch.rand(1, n, 3, size, size)})
    module.eval()
    params = sum(p.numel() for p in module.parameters())
    times = []
    with torch.inference_mode():
        for i in range(args.repeats + 1):
            t0 = time.perf_counter()
            module(*inputs[0], **inputs[1])
            if i:  # the first run warms up allocators and kernels
                times.append((time.perf_counter() - t0) * 1e3)
    return params, statistics.median(times)


def _cmd_describe(args, registry: Registry, out) -> None:
    kinds = [args.kind] if args.kind else [k for k in KINDS if args.name in registry.names(k)]
    if not kinds:
        every = [n for k in KINDS for n in registry.names(k)]
        close = difflib.get_close_matches(args.name, every, n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
        raise UnknownNameError(
            f"no generator, attention module or discriminator is named {args.name!r}.{hint} "
            f"'svbrdf-models list' shows what is installed. {REINSTALL_HINT}"
        )
    if len(kinds) > 1:
        raise RegistryError(
            f"{args.name!r} is registered as {' and '.join(_NOUNS[k] for k in kinds)}; pick one with --kind"
        )
    print(registry.describe(kinds[0], args.name).format(), file=out)


def _cmd_show(args, registry: Registry, out) -> None:
    from .modelfile import PRETRAINED, card_path, load_model

    model = load_model(args.source)
    info = model.provenance
    lines = [model.describe(), f"  SHA-256     {model.sha256}"]
    lines.append("  config      " + ", ".join(f"{k}={v}" for k, v in model.config.items()))
    lines.append(
        f"  recipe      {info.get('recipe')} ({info.get('size')}), code {info.get('git_sha', 'unknown')}"
    )
    lines.append(
        f"  training    {model.steps} steps, {info.get('samples', '?')} samples, "
        f"{float(info.get('train_seconds', 0)) / 3600:.2f} h on {info.get('hardware', 'unknown')}"
    )
    for source in (info.get("data") or {}).get("sources", []):
        files = source.get("files") or []
        where = f" {', '.join(source.get('path', []))} ({len(files)} files)" if "path" in source else ""
        weight = f" weight {source['weight']}" if "weight" in source else ""
        lines.append(f"  data        {source['source']}{weight}{where}")
    for key, value in sorted(model.metrics.items()):
        lines.append(f"  metric      {key} = {value:.4g}")
    for name, effect in (info.get("half_effect") or {}).items():
        lines.append(f"  fp16 effect {name}: RMSE {effect['rmse']:.1e}, max {effect['max']:.1e}")
    if model.source == f"pretrained:{PRETRAINED}":
        lines.append(f"  card        {card_path()}")
    print("\n".join(lines), file=out)


def _cmd_predict(args, registry: Registry, out) -> int:
    """``predict``: the options checked, the model loaded and announced, the photos captured."""
    from svbrdf_render.files import check_output_folder

    from .batch import capture_batch, check_material_folders, pick_device

    options = _capture_options(args)
    device = pick_device(args.device)  # a GPU that is not there is named as such
    check_output_folder(args.out, "-o")  # before the model is loaded and the first photo is done
    check_material_folders(args.photos, args.out)
    if args.tiles and args.map_size is not None:  # refused before the model loads
        from .capture import check_tiled_memory

        check_tiled_memory(args.map_size, f"--tiles --map-size {args.map_size}")
    model = _load_predict_model(args.model, device, args.map_size if args.tiles else None)
    summary = {"model": model.source, "step": model.steps, "resolution": model.resolution,
               "refine": args.refine, "refine_seconds": args.refine_seconds}  # fmt: skip
    return capture_batch(model, args.photos, args.out, options, prog="svbrdf-models", summary=summary)


def _capture_options(args):
    """The :class:`~svbrdf_models.capture.CaptureOptions` of ``predict``'s flags; flags that go
    with another one given alone, and a scene that cannot be a photo's capture, are refused."""
    from .batch import load_scene
    from .capture import CaptureOptions
    from .errors import DataError

    if args.map_size is not None and not (args.tiles or args.refine):
        raise DataError("--map-size goes with --tiles or --refine STEPS > 0")
    alone = [
        f for f, v in (("--refine-seconds", args.refine_seconds), ("--scene", args.scene)) if v is not None
    ]
    if alone and not args.refine:
        raise DataError(f"{' and '.join(alone)} go(es) with --refine STEPS > 0, not --refine 0")
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
        scene=None if args.scene is None else load_scene(args.scene),
        backend=args.backend,
    )


def _load_predict_model(source, device, tile_size):
    """The model of --model (the shipped one when None), announced on stderr."""
    from .errors import DataError
    from .modelfile import PRETRAINED, card_path, load_model

    if source is None:
        print(
            f"no --model: using the model shipped with svbrdf-models (pretrained:{PRETRAINED}; "
            f"its card: {card_path()})",
            file=sys.stderr,
        )
    model = load_model(source or "pretrained", device)
    if tile_size is not None and tile_size < model.resolution:
        raise DataError(f"--map-size {tile_size} is smaller than the model's resolution ({model.resolution})")
    print(model.describe(), file=sys.stderr)
    if tile_size is not None:
        from .capture import available_memory, tile_count, tiled_capture_bytes

        have = available_memory()
        print(
            f"--tiles --map-size {tile_size}: {tile_count(tile_size, model.resolution)} tiles of "
            f"{model.resolution} px per photo, about {tiled_capture_bytes(tile_size) / 2**30:.1f} GiB "
            f"of memory" + (f" ({have / 2**30:.1f} GiB available)" if have is not None else ""),
            file=sys.stderr,
        )
    return model


def main(argv: list[str] | None = None, registry: Registry | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # a usage error (one line, exit 2) or --help (exit 0)
        return int(e.code or 0)
    try:
        if args.command == "predict":  # the registry is read when the model's generator is built
            return _cmd_predict(args, registry, sys.stdout)
        registry = registry or default_registry()
        commands = {"list": _cmd_list, "describe": _cmd_describe, "show": _cmd_show}
        commands[args.command](args, registry, sys.stdout)
    except SVBRDFError as e:  # RegistryError, a model file, a photo option, a scene: one line
        print(f"svbrdf-models: error: {e}", file=sys.stderr)
        return exit_status(e)
    except OSError as e:
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"svbrdf-models: error: {where}{e.strerror or e}", file=sys.stderr)
        return exit_status(e)
    except KeyboardInterrupt:
        print("svbrdf-models: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
