"""``svbrdf-render``: render materials from the command line.

Materials are given as a Des18 strip (``sample.png``), a folder holding
``normal/diffuse/roughness/specular.png``, or a built-in example (``example:tiles``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch

from . import __version__
from .effects import DES18_EFFECTS, EFFECTS
from .errors import SVBRDFError, exit_status
from .maps import SVBRDF
from .plumbing import (
    EXIT_STATUS,
    INTERRUPTED,
    MAX_THREADS,
    THREADS_HELP,
    OneLineParser,
    choose_threads,
    float_range,
    int_range,
)
from .renderer import BACKENDS
from .scene import DES18_DISTANCE, Camera, PointLight, Scene

EPILOG_RENDER = """\
examples:
  svbrdf-render render example:tiles -o tiles.png --gamma 2.2
  svbrdf-render render '0000004;PolishedMarbleFloor_01Xmetal_bumpy_squares;4X2.png' -o marble.png
  svbrdf-render render my_maps/ -o lit.png --light 0.5 0.5 2 --intensity 20
  svbrdf-render scene -o studio.yaml   # write a scene template, edit it, then:
  svbrdf-render render example:leather --scene studio.yaml -o leather.png

Without --scene, the scene is the Des18 capture: an on-axis camera at --distance with a
co-located flash, effects diffuse, specular, fresnel, masking, cosine, falloff, linear
output (no gamma) like the Des18 inputs. The default intensity, pi * distance^2, makes a
white Lambertian patch reach 1.0 at its centre.
"""

EPILOG_PREVIEW = """\
example:
  svbrdf-render preview example:brushed-metal -o metal-grid.png --grid 4

The light moves over a --grid x --grid lattice at height --height above the patch,
spanning [-spread, spread] in x and y; the camera stays on the axis. All configurations
render in one batched call. The default intensity, pi * height^2, brings a white
Lambertian patch right under a light to 1.0.
"""


#: Largest --size, and largest side of a preview grid: 8192 px is 0.8 GB per map in float32.
MAX_SIZE = 8192
#: Largest |--exposure|: 2**64 already turns any rendering white.
MAX_EV = 64.0


class CliError(SVBRDFError):
    """A user error: printed as one line, exit code 2."""


def _examples():
    from .examples import EXAMPLES, example_material

    return EXAMPLES, example_material


def load_material(spec: str, size: int | None = None) -> SVBRDF:
    """Read a material from a Des18 strip, a map folder or ``example:NAME``."""
    from .formats.mapfiles import read_des18, read_map_folder

    if spec.startswith("example:"):
        examples, make = _examples()
        name = spec.split(":", 1)[1]
        if name not in examples:
            raise CliError(f"unknown example {name!r}; choose from {', '.join(examples)}")
        return make(name, size or 256)
    path = Path(spec)
    if path.is_dir():
        m = read_map_folder(path)
    elif path.is_file():
        m = read_des18(path).svbrdf
    else:
        raise CliError(
            f"{spec}: no such file or folder (give a Des18 strip PNG, a folder of maps, "
            f"or example:NAME)"
        )
    if size is not None and m.size != (size, size):
        m = m.resize(size)
    return m


def _effects_arg(text: str) -> list[str]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    for name in names:
        if name not in EFFECTS:
            raise argparse.ArgumentTypeError(
                f"unknown effect {name!r}; known: {', '.join(EFFECTS)}"
            )
    return names


#: Flags that describe the scene themselves: with --scene the file does, and they would be ignored.
_SCENE_FLAGS = ("distance", "intensity", "light", "effects")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _check_flags(args, *, light_moves: bool = False) -> None:
    """Refuse flags that would have no effect in this combination (no flag is silently ignored)."""
    if args.scene:
        given = [_flag(n) for n in _SCENE_FLAGS if getattr(args, n) is not None]
        if given:
            raise CliError(
                f"{', '.join(given)} with --scene {args.scene}: the scene file sets the camera, lights and "
                "effects; edit it (or drop --scene); only --exposure and --gamma add to a scene file"
            )
    if light_moves and args.light is not None:
        raise CliError(
            f"--light {' '.join(f'{v:g}' for v in args.light)}: preview moves the light over --grid "
            "positions at --height; use render for one light position"
        )
    if args.light is not None and args.light[2] <= 0:
        raise CliError(
            f"--light {' '.join(f'{v:g}' for v in args.light)}: Z must be > 0 (the light above the "
            "patch, which lies at z = 0); below it, nothing is lit"
        )


def _scene_from_args(args) -> Scene:
    if args.scene:
        scene = Scene.load(args.scene)
    else:
        d = args.distance if args.distance is not None else DES18_DISTANCE
        intensity = args.intensity if args.intensity is not None else math.pi * d * d
        camera = Camera(torch.tensor([0.0, 0.0, d]), 2 * math.degrees(math.atan(1 / d)))
        light_pos = torch.tensor(args.light) if args.light else camera.position
        effects = list(args.effects) if args.effects else list(DES18_EFFECTS)
        scene = Scene(camera, (PointLight(light_pos, intensity),), effects)
    extra = dict(scene.effects)
    if args.exposure is not None:
        extra["exposure"] = {"ev": args.exposure}
    if args.gamma is not None:
        extra["gamma"] = {"gamma": args.gamma}
    return scene.with_effects(extra)


def _add_scene_flags(p: argparse.ArgumentParser, gamma_default) -> None:
    g = p.add_argument_group("scene")
    g.add_argument("--scene", metavar="YAML", help="scene file (camera, lights, effects); "
                   "only --exposure and --gamma may be added to it")
    g.add_argument("--distance", type=float_range(0, above=True), default=None,
                   help=f"camera distance, > 0 (default {DES18_DISTANCE}, Des18)")
    g.add_argument("--intensity", type=float_range(0), default=None,
                   help="light intensity, >= 0 (default pi * distance^2)")
    g.add_argument("--light", type=float_range(), nargs=3, metavar=("X", "Y", "Z"),
                   help="light position, Z > 0 (default: a flash at the camera)")
    g.add_argument("--effects", type=_effects_arg, metavar="LIST",
                   help=f"comma-separated effects (default {','.join(DES18_EFFECTS)}); "
                   f"known: {', '.join(EFFECTS)}")
    g.add_argument("--exposure", type=float_range(-MAX_EV, MAX_EV), metavar="EV",
                   help=f"add an exposure of EV stops (-{MAX_EV:g} to {MAX_EV:g})")
    g.add_argument("--gamma", type=float_range(0, above=True), default=gamma_default,
                   help=f"encode the output with x^(1/GAMMA), GAMMA > 0 "
                   f"(default: {gamma_default or 'linear'})")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="svbrdf-render",
        description="Render SVBRDF maps (normal, diffuse, roughness, specular) of a flat patch "
        "under a camera and lights. MATERIAL is a Des18 strip PNG (input|normal|diffuse|"
        "roughness|specular), a folder with normal/diffuse/roughness/specular.png, or a "
        "built-in example:tiles, example:brushed-metal, example:leather.",
        epilog=EXIT_STATUS,
    )
    parser.add_argument("--version", action="version", version=f"svbrdf-render {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("render", help="render a material to a PNG", description="Render one "
                       "material under a scene and write a PNG.", epilog=EPILOG_RENDER,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("material", metavar="MATERIAL")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.add_argument("--size", type=int_range(1, MAX_SIZE),
                   help=f"resample the maps to SIZE x SIZE first (1 to {MAX_SIZE})")
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="PNG bit depth (default 8)")
    p.add_argument("--backend", choices=BACKENDS, default="eager",
                   help="compiled = torch.compile (faster for repeated renders, slow first call)")
    _add_scene_flags(p, None)
    p.add_argument("--threads", type=int_range(1, MAX_THREADS), metavar="N", help=THREADS_HELP)

    p = sub.add_parser("preview", help="a grid of renderings under moving light",
                       description="Relight a material from several light positions and "
                       "write the renderings as one grid PNG.", epilog=EPILOG_PREVIEW,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("material", metavar="MATERIAL")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.add_argument("--grid", type=int_range(1, 16), default=3, help="lights per side, 1 to 16 (default 3)")
    p.add_argument("--spread", type=float_range(0), default=1.0,
                   help="light offsets span [-S, S], S >= 0 (default 1)")
    p.add_argument("--height", type=float_range(0, above=True), default=1.5,
                   help="light height, > 0 (default 1.5)")
    p.add_argument("--size", type=int_range(1, MAX_SIZE),
                   help=f"resample the maps to SIZE x SIZE first; the grid is at most {MAX_SIZE} px a side")
    _add_scene_flags(p, 2.2)
    p.add_argument("--threads", type=int_range(1, MAX_THREADS), metavar="N", help=THREADS_HELP)

    p = sub.add_parser("scene", help="write the default scene as YAML (a template to edit)")
    p.add_argument("-o", "--output", help="file to write (default: print)")

    sub.add_parser("effects", help="list the effects a scene can declare, with parameters")
    return parser


def _cmd_render(args) -> None:
    from .formats.mapfiles import write_image
    from .renderer import render

    _check_flags(args)
    m = load_material(args.material, args.size)
    scene = _scene_from_args(args)
    if scene.config_shape != torch.Size():
        raise CliError(f"{args.scene}: the render command takes one configuration per scene")
    img = render(m, scene, backend=args.backend)[0]
    out = write_image(args.output, img, bits=args.bits)
    print(f"wrote {out} ({img.shape[2]}x{img.shape[1]}, effects: {', '.join(scene.effects)})")


def _cmd_preview(args) -> None:
    from .formats.mapfiles import write_image
    from .renderer import render

    _check_flags(args, light_moves=True)
    if args.size is not None and args.grid * args.size > MAX_SIZE:
        raise CliError(
            f"--grid {args.grid} x --size {args.size} makes a {args.grid * args.size} px grid; keep "
            f"grid x size within {MAX_SIZE} px (lower --size or --grid)"
        )
    m = load_material(args.material, args.size)
    side = args.grid * max(m.size)
    if side > MAX_SIZE:
        raise CliError(
            f"{args.material}: {max(m.size)} px maps on a --grid {args.grid} make a {side} px grid; keep "
            f"it within {MAX_SIZE} px (give --size, or a smaller --grid)"
        )
    if args.intensity is None and not args.scene:
        # A white Lambertian patch right under a light then reaches 1.0.
        args.intensity = math.pi * args.height**2
    base = _scene_from_args(args)
    if args.scene and (len(base.lights) > 1 or base.config_shape != torch.Size()):
        raise CliError(
            f"{args.scene}: preview moves one light over the grid; the scene has {len(base.lights)} "
            f"light(s) and configuration shape {tuple(base.config_shape)}: keep one light and one "
            "configuration"
        )
    t = torch.linspace(-args.spread, args.spread, args.grid) if args.grid > 1 else torch.zeros(1)
    ys, xs = torch.meshgrid(-t, t, indexing="ij")  # top row = light above the top edge
    pos = torch.stack([xs, ys, torch.full_like(xs, args.height)], dim=-1).reshape(-1, 3)
    light = base.point_lights[0]
    scene = Scene(base.camera, (PointLight(pos, light.intensity, light.color),), base.effects)
    imgs = render(m, scene)[0]  # (K, 3, H, W)
    k, c, h, w = imgs.shape
    n = args.grid
    grid = imgs.reshape(n, n, c, h, w).permute(2, 0, 3, 1, 4).reshape(c, n * h, n * w)
    out = write_image(args.output, grid)
    print(f"wrote {out} ({args.grid}x{args.grid} renderings of {w}x{h})")


def _cmd_scene(args) -> None:
    from .scene import Flash

    text = Scene(Camera(), (Flash(math.pi * 2.2 * 2.2),), DES18_EFFECTS).to_yaml()
    if args.output:
        from .plumbing import write_text

        write_text(args.output, text)
        print(f"wrote {args.output}")
    else:
        print(text, end="")


def _cmd_effects(args) -> None:
    for spec in EFFECTS.values():
        params = ", ".join(f"{k}={v!r}" for k, v in spec.defaults.items()) or "-"
        print(f"{spec.name:<11} {spec.phase:<8} {spec.doc:<32} {params}")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # a usage error (one line, exit 2) or --help (exit 0)
        return int(e.code or 0)
    commands = {"render": _cmd_render, "preview": _cmd_preview, "scene": _cmd_scene, "effects": _cmd_effects}
    try:
        if args.command in ("render", "preview"):
            choose_threads(args.threads)
        commands[args.command](args)
    except (CliError, SVBRDFError, ImportError) as e:
        print(f"svbrdf-render: error: {e}", file=sys.stderr)
        return exit_status(e)
    except OSError as e:
        print(f"svbrdf-render: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return exit_status(e)
    except KeyboardInterrupt:
        print("svbrdf-render: interrupted", file=sys.stderr)
        return INTERRUPTED
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
