#!/usr/bin/env python
"""A batch on a machine that gets busy half-way through (issue 47).

One ``svbrdf-models predict`` over ``--photos`` photos of 256 px (rendered example materials);
when ``--busy-at`` of them are done, ``--busy`` CPU-bound processes start beside it (each a
``while True: pass``) and run until the batch ends. Per photo, ``material.json``'s
``refine.seconds`` (the refinement's wall time) is read back, and the photos done before and
after the busy processes started are compared, for two ways of choosing threads:

* ``free cores`` (the default): one torch thread per free core, chosen again before each photo;
* ``chosen once``: ``--threads`` fixed at the machine's cores, what the command did before
  (threads chosen once, at the start, then spinning against the other processes).

Run it on an otherwise idle machine: another program's load is part of what it measures.

Usage::

    .venv/bin/python benchmarks/busy_batch.py                 # 16 photos, busy from the 8th, 2 busy
    .venv/bin/python benchmarks/busy_batch.py --photos 24 --busy-at 12 --busy 2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(sys.executable).parent
BUSY = "while True: pass"


def _photos(folder: Path, n: int, size: int) -> list[str]:
    from svbrdf_render import Scene, render, write_image
    from svbrdf_render.examples import example_material
    from svbrdf_render.formats.mapfiles import linear_to_srgb

    names = ["tiles", "leather", "brushed-metal"]
    out = []
    for i in range(n):
        material = example_material(names[i % len(names)], size)
        photo = render(material, Scene.flash(intensity=8.0 + i % 5)).clamp(0, 1)[0]
        out.append(str(write_image(folder / f"p{i:03d}.png", linear_to_srgb(photo))))
    return out


def _done(out: Path) -> list[Path]:
    return sorted(out.glob("p*/material.json"))


def _batch(
    photos: list[str], out: Path, threads: int | None, busy_at: int, busy: int
) -> tuple[list[float], int, str]:
    """Per photo, its refinement seconds; the photos done when the busy processes started; what
    the command printed on stderr."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    cmd = [str(HERE / "svbrdf-models"), "predict", *photos, "-o", str(out), "--relit", "none"]
    if threads is not None:
        cmd += ["--threads", str(threads)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    hogs: list[subprocess.Popen] = []
    started_at = None
    try:
        while proc.poll() is None:
            if not hogs and len(_done(out)) >= busy_at:
                hogs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(busy)]
                started_at = len(_done(out))
            time.sleep(0.05)
    finally:
        for h in hogs:
            h.kill()
    err = proc.stderr.read() if proc.stderr else ""
    if proc.returncode != 0:
        sys.exit(f"busy_batch: predict failed ({proc.returncode}): {err[-2000:]}")
    seconds = [json.loads(p.read_text())["refine"]["seconds"] for p in _done(out)]
    return seconds, (started_at if started_at is not None else len(seconds)), err


def _row(label: str, seconds: list[float], start: int) -> str:
    before, after = seconds[:start], seconds[start + 1:]  # the photo under way at the start is left out
    base = statistics.median(before) if before else float("nan")
    slow = sum(s > 3 * base for s in after)
    return (f"| {label} | {len(before)} | {base:.1f} | {len(after)} | "
            f"{statistics.median(after) if after else float('nan'):.1f} | "
            f"{max(after) if after else float('nan'):.1f} | {slow} |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", type=int, default=16)
    ap.add_argument("--busy-at", type=int, default=None, help="photos done before the busy processes start")
    ap.add_argument("--busy", type=int, default=2, help="CPU-bound processes started beside the batch")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--modes", default="free,once", help="free (chosen per photo), once (--threads CORES)")
    args = ap.parse_args(argv)
    busy_at = args.busy_at if args.busy_at is not None else args.photos // 2
    cores = len(os.sched_getaffinity(0))
    with tempfile.TemporaryDirectory() as tmp:
        photos = _photos(Path(tmp), args.photos, args.size)
        rows = []
        for mode in args.modes.split(","):
            threads = None if mode == "free" else cores
            seconds, start, err = _batch(photos, Path(tmp) / f"out-{mode}", threads, busy_at, args.busy)
            label = "free cores, chosen per photo" if mode == "free" else f"--threads {cores}, chosen once"
            rows.append(_row(label, seconds, start))
            changes = [line for line in err.splitlines() if ": now " in line]
            print(f"{label}: per photo {', '.join(f'{s:.1f}' for s in seconds)} s; busy from photo {start + 1}; "
                  f"thread changes said: {len(changes)}", file=sys.stderr)
    print(f"{args.photos} photos of {args.size} px, {args.busy} CPU-bound processes started after "
          f"{busy_at} photos, {cores} cores; refinement seconds per photo (material.json)\n")
    print("| threads | photos before | median s | photos after | median s | max s | after > 3x before |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
