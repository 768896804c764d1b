#!/usr/bin/env python
"""What a user waits for and what memory it takes: the whole ``svbrdf-models predict`` command
(default options: the shipped model, 100 refinement steps, maps at most 1024 px, the relit
GIF) on one photo of 256 px, 1 MP and 12 MP, idle and with CPU-bound processes beside it.

Each run is a fresh process (start-up, imports, model load, photo decode, network,
refinement, every file written); the table gives its wall time and peak memory (the child's
maximum resident set). The photos are JPEGs made here: a procedural material rendered under
the phone flash, at 256x256, 1000x1000 and 4000x3000 pixels. ``--load N`` starts N busy
Python loops beside each run (they spin on one core each, as a compile or another fit would),
and reports the machine's 1-minute load average; ``--threads`` passes ``--threads`` to
predict (default: its own choice, one per free core).

Usage::

    .venv/bin/python benchmarks/capture_speed.py                 # idle machine
    .venv/bin/python benchmarks/capture_speed.py --load 2        # two CPU-bound processes beside it
    .venv/bin/python benchmarks/capture_speed.py --sizes 256 --threads 2 --load 2
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIZES = {"256": (256, 256), "1MP": (1000, 1000), "12MP": (4000, 3000)}


def _photo(path: Path, width: int, height: int) -> Path:
    import torch
    import torch.nn.functional as F

    from svbrdf_render import linear_to_srgb
    from svbrdf_train.data.procedural import ProceduralMaterials
    from svbrdf_train.data.simulated_photo import PhotoSettings

    sample = ProceduralMaterials(1, 256, seed=3, photo=PhotoSettings.preset("phone"))[0]["input"]
    big = F.interpolate(sample[None], size=(height, width), mode="bicubic", align_corners=False)[0]
    from PIL import Image

    pixels = (linear_to_srgb(big.clamp(0, 1)) * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
    Image.fromarray(pixels).save(path, quality=92)
    return path


def _spin() -> None:  # pragma: no cover - a busy loop, killed by the parent
    while True:
        pass


def _run(photo: Path, out: Path, threads: int | None) -> tuple[float, float, str]:
    """Wall seconds, peak MB of the child, and its threads line."""
    cmd = [sys.executable, "-m", "svbrdf_models", "predict", str(photo), "-o", str(out)]
    cmd += ["--threads", str(threads)] if threads else []
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"capture_speed: predict failed on {photo.name}:\n{done.stderr[-2000:]}")
    peak = max(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, before) / 1024
    line = next((x for x in done.stderr.splitlines() if "torch thread" in x), "?")
    return seconds, peak, line


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="256,1MP,12MP", help="photos: 256, 1MP, 12MP (comma-separated)")
    ap.add_argument("--load", type=int, default=0, help="CPU-bound processes beside each run")
    ap.add_argument("--threads", type=int, default=None, help="predict --threads (default: its own choice)")
    args = ap.parse_args(argv)
    sizes = [s.strip() for s in args.sizes.split(",") if s.strip()]
    spinners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.load)]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        photos = {s: _photo(root / f"photo-{s}.jpg", *SIZES[s]) for s in sizes}
        for p in spinners:
            p.start()
        time.sleep(5 if spinners else 0)  # let the load average see them
        try:
            print("| photo | wall s | peak MB | threads | load (1 min) | beside it |")
            print("| --- | ---: | ---: | --- | ---: | ---: |")
            for s, photo in photos.items():
                seconds, peak, line = _run(photo, root / f"out-{s}", args.threads)
                print(f"| {s} ({'x'.join(map(str, SIZES[s]))}) | {seconds:.1f} | {peak:.0f} | {line} "
                      f"| {os.getloadavg()[0]:.1f} | {args.load} |", flush=True)  # fmt: skip
        finally:
            for p in spinners:
                p.kill()


if __name__ == "__main__":
    main()
