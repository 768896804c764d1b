"""How far one ``svbrdf-models predict`` call walks through the project's files.

A newcomer follows a call by reading the files it passes through; each time the call comes back
to a file it had left, the reader flips back. This script runs one ``predict`` of a photo
(refinement 100, the relit GIF: the defaults) under :func:`sys.setprofile` and records the
project file (any ``packages/*/src/...`` module) of every Python function called, in order.
Consecutive calls in one file count once. The command runs once untraced first, so that the
walk is the call's, not the imports'. It prints:

- files: the project files the call passes through;
- returns: transitions into a file already visited earlier in the walk, each distinct
  ``(from, into)`` pair counted once (a loop that repeats the same hops, such as 100 refinement
  steps, counts as one walk);
- hops: all transitions between files, each distinct pair once.

Run it on another checkout with ``PYTHONPATH`` naming that checkout's ``packages/*/src``
folders to compare two versions (the figures of issue 38 were measured so)::

    .venv/bin/python benchmarks/predict_walk.py
    PYTHONPATH=old/packages/svbrdf-render/src:old/packages/svbrdf-models/src \\
        .venv/bin/python benchmarks/predict_walk.py
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path


def record_walk(argv: list[str], warm_argv: list[str]) -> list[str]:
    """The project files of the Python calls ``svbrdf_models.cli.main(argv)`` makes, in order,
    consecutive repeats collapsed, after one untraced run of ``warm_argv`` (imports done)."""
    from svbrdf_models.cli import main

    if main(warm_argv) != 0:
        raise SystemExit("the warm-up predict failed")
    walk: list[str] = []

    def tracer(frame, event, arg):
        if event != "call":
            return
        name = frame.f_code.co_filename
        if "/packages/" in name and "/src/" in name:
            short = name.split("/src/", 1)[1]
            if not walk or walk[-1] != short:
                walk.append(short)

    sys.setprofile(tracer)
    try:
        code = main(argv)
    finally:
        sys.setprofile(None)
    if code != 0:
        raise SystemExit(f"predict exited {code}")
    return walk


def figures(walk: list[str]) -> dict[str, int]:
    """Files, distinct returns and distinct hops of a walk (see the module)."""
    seen, returns, hops = set(), set(), set()
    for prev, cur in zip(walk, walk[1:], strict=False):
        seen.add(prev)
        hops.add((prev, cur))
        if cur in seen:
            returns.add((prev, cur))
    return {"files": len(set(walk)), "returns": len(returns), "hops": len(hops)}


def merged(walk: list[str], moves: dict[str, str]) -> list[str]:
    """``walk`` as if each file of ``moves`` were merged into its value (consecutive repeats
    collapsed again): what merging two modules would do to the figures, before doing it."""
    out: list[str] = []
    for f in walk:
        f = moves.get(f, f)
        if not out or out[-1] != f:
            out.append(f)
    return out


def _move(text: str) -> tuple[str, str]:
    src, sep, dst = text.partition("=")
    if not sep or not src.endswith(".py") or not dst.endswith(".py"):
        raise argparse.ArgumentTypeError(f"expected FILE=INTO, two paths as --list prints them, got {text!r}")
    return src, dst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=256, help="side of the photo [256]")
    parser.add_argument("--refine", type=int, default=100)
    parser.add_argument("--list", action="store_true", help="print the files in the order first visited")
    parser.add_argument("--merge", type=_move, action="append", default=[], metavar="FILE=INTO",
                        help="also print the figures as if FILE were merged into INTO (paths as --list "
                        "prints them, e.g. svbrdf_models/capture/relight.py=svbrdf_models/capture/"
                        "figures.py); repeat for several")
    args = parser.parse_args()
    import torch

    from svbrdf_render import Scene, render, write_image
    from svbrdf_render.examples import example_material

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        photo = Path(tmp) / "photo.png"
        image = render(example_material("tiles", args.size), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
        write_image(photo, image)
        argv = ["predict", str(photo), "--refine", str(args.refine), "--threads", "1", "-o"]
        walk = record_walk([*argv, str(Path(tmp) / "out")], [*argv, str(Path(tmp) / "warm")])
    f = figures(walk)
    print(f"files {f['files']}  returns {f['returns']}  hops {f['hops']}")
    for src, dst in args.merge:
        if src not in walk:
            print(f"  {src}: not in the walk (see --list)")
            continue
        g = figures(merged(walk, {src: dst}))
        print(f"  {src} merged into {dst}: files {g['files']}  returns {g['returns']}  hops {g['hops']}")
    if len(args.merge) > 1:
        g = figures(merged(walk, dict(args.merge)))
        print(f"  all {len(args.merge)} merges: files {g['files']}  returns {g['returns']}  hops {g['hops']}")
    if args.list:
        print("\n".join(dict.fromkeys(walk)))


if __name__ == "__main__":
    main()
