#!/usr/bin/env python
"""How long a user waits for maps: loading a model file, then one 256x256 photo to maps.

Prints a Markdown table for a model (default: the one shipped with svbrdf-models):

* load ms: ``svbrdf_models.load_model`` (read, SHA-256, rebuild, weights in), median of runs;
* predict ms: ``model.predict`` on one linear 256x256 photo (resized to the model's resolution
  inside, as ``svbrdf-train predict`` does), after one warm-up, median of ``--repeats``;
* the same for a float16 copy of the file when ``--half`` is given (the weights are widened to
  float32 to run, so only the loading and the file size change).

``svbrdf-train predict`` does more per photo (the re-rendering fit of the flash and the relit
preview): ``--cli`` also times the whole command on one photo with ``--relit none``, in a
fresh process (Python start-up and imports included).

Usage::

    .venv/bin/python benchmarks/predict_speed.py                     # the shipped model, 2 threads
    .venv/bin/python benchmarks/predict_speed.py --model m.pt --threads 1 --cli
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

import svbrdf_models as sm
from svbrdf_models.modelfile.files import model_dict, pretrained_path, save_model


def _median_ms(fn, repeats: int, warm: bool = True) -> float:
    if warm:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def _photo(size: int) -> torch.Tensor:
    """A flash-like linear photo: a bright centre falling off, with texture."""
    g = torch.Generator().manual_seed(0)
    y, x = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    falloff = 1 / (1 + 4 * (x * x + y * y))
    return (0.6 * falloff * (0.5 + 0.5 * torch.rand(3, size, size, generator=g))).clamp(0, 1)


def _row(label: str, source: str, repeats: int, photo: torch.Tensor) -> str:
    load = _median_ms(lambda: sm.load_model(source), max(3, repeats // 4), warm=False)
    model = sm.load_model(source)
    predict = _median_ms(lambda: model.predict(photo), repeats)
    size = Path(pretrained_path() if source == "pretrained" else source).stat().st_size / 2**20
    return f"| {label} | {model.resolution} | {size:.1f} | {load:.0f} | {predict:.0f} |"


def _cli_seconds(source: str, photo: torch.Tensor, threads: int) -> float:
    from svbrdf_render import write_image
    from svbrdf_render.formats.mapfiles import linear_to_srgb

    with tempfile.TemporaryDirectory() as tmp:
        path = write_image(Path(tmp) / "photo.png", linear_to_srgb(photo))
        env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
        cmd = [sys.executable, "-m", "svbrdf_train", "predict", str(path), "--model", source, "-o",
               str(Path(tmp) / "maps"), "--relit", "none"]  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="pretrained", help="a model file, URL, MLflow URI or pretrained")
    p.add_argument("--size", type=int, default=256, help="side of the photo in pixels [256]")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--threads", type=int, default=2, help="torch threads [2]")
    p.add_argument("--half", action="store_true", help="also time a float16 copy of the file")
    p.add_argument("--cli", action="store_true", help="also time svbrdf-train predict on one photo")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    photo = _photo(args.size)
    model = sm.load_model(args.model)
    print(
        f"{model.describe()}\n{args.size}x{args.size} photo; torch {torch.__version__}, "
        f"{args.threads} threads, {platform.processor() or platform.machine()}, median of {args.repeats}\n",
        file=sys.stderr,
    )
    rows = ["| file | resolution | MiB | load ms | predict ms |", "| --- | ---: | ---: | ---: | ---: |"]
    rows.append(_row(f"{args.model} ({model.precision})", args.model, args.repeats, photo))
    if args.half:
        with tempfile.TemporaryDirectory() as tmp:
            half = Path(tmp) / "half.pt"
            state = {k: v for k, v in model.generator.state_dict().items()}
            save_model(
                half, model_dict(model.name, model.config, state, resolution=model.resolution, half=True)
            )
            rows.append(_row(f"{args.model} (fp16 copy)", str(half), args.repeats, photo))
    print("\n".join(rows))
    if args.cli:
        seconds = _cli_seconds(args.model, photo, args.threads)
        print(f"\nsvbrdf-train predict, one {args.size}x{args.size} photo, --relit none: {seconds:.1f} s")


if __name__ == "__main__":
    main()
