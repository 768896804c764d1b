#!/usr/bin/env python
"""The constants of the ``mean`` and ``photo`` baselines, read off a Des18 folder, and what they score.

Each constant is the one that minimises the mean per-image RMSE of its own map (on the stored
encodings, as ``svbrdf-bench`` scores them) over the test samples of the folder, brought to
``--resolution`` the benchmark's way (whole tiles, area filter: ``svbrdf_bench.testset``):

- ``mean``:  diffuse scale (diffuse = scale x the photo's per-channel median), roughness, specular;
- ``photo``: diffuse scale (diffuse = scale x the photo with the flash fall-off divided out,
  clamped); its roughness is the same constant as ``mean``'s (the roughness map's own optimum)
  and its specular is 0 by definition.

A 1-D search per constant (a grid, then a finer grid around its best point), rounded to 3
decimals. Then both baselines, built from the registry with these constants and with the
registered defaults, are scored by ``svbrdf_bench.metrics.evaluate`` (RMSE per map and on the
6 evaluation renderings). As a check on the render figure, the render RMSE alone is also minimised
on coarse grids (``mean``: roughness x specular, its diffuse scale fixed; ``photo``: its diffuse
scale): it shows how much constants tuned on renderings would gain over the map-tuned defaults.

The constants are read off the very images they are scored on, which favours the baselines.

Usage::

    .venv/bin/python benchmarks/baseline_constants.py                       # DATA/des18-dev, 128 px
    .venv/bin/python benchmarks/baseline_constants.py --data DIR --resolution 256
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

import svbrdf_models as sm
from svbrdf_bench.metrics import evaluate
from svbrdf_bench.testset import test_set
from svbrdf_models.networks.baselines import flash_falloff
from svbrdf_render import DES18_DISTANCE, SVBRDF
from svbrdf_render.compare import render_rmse

REPO = Path(__file__).resolve().parents[1]
COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")


def minimise(score: Callable[[float], float], lo: float, hi: float, steps: int = 41) -> float:
    """The argmin of ``score`` on [lo, hi]: a grid, then two finer grids around the best point."""
    for _ in range(3):
        grid = np.linspace(lo, hi, steps)
        values = [score(float(v)) for v in grid]
        k = int(np.argmin(values))
        step = grid[1] - grid[0]
        lo, hi = max(grid[0], grid[k] - step), min(grid[-1], grid[k] + step)
    return round(float(grid[k]), 3)


def rmse(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Mean over images of the per-image RMSE."""
    return float((pred - target).square().flatten(1).mean(1).sqrt().mean())


def scores(name: str, config: dict, photos: torch.Tensor, maps: SVBRDF) -> dict[str, float]:
    g = sm.create_generator(name, config).eval()
    with torch.no_grad():
        figures = evaluate(g(photos), maps)
    return {c: float(figures[f"rmse/{c}"].mean()) for c in COLUMNS}


def row(label: str, figures: dict[str, float]) -> str:
    return f"| {label} | " + " | ".join(f"{figures[c]:.4f}" for c in COLUMNS) + " |"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "des18-dev")
    parser.add_argument("--resolution", type=int, default=128)
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"baseline_constants: {args.data}: no such folder (a Des18 folder is needed)", file=sys.stderr)
        return 2
    torch.set_grad_enabled(False)
    test = test_set(args.data, args.resolution, 0)
    items = [test[i] for i in range(len(test))]
    photos = torch.stack([s["input"] for s in items]).float()
    maps = SVBRDF.unpack(torch.stack([s["maps"] for s in items]).float(), validate=False)
    print(f"{test.description}: {len(items)} images\n")

    median = photos.flatten(2).median(dim=2).values[:, :, None, None]
    flat = photos / flash_falloff(args.resolution, args.resolution, DES18_DISTANCE)
    d, r, s = maps.diffuse, maps.roughness, maps.specular

    mean_scale = minimise(lambda k: rmse((k * median).clamp(0, 1).expand_as(d), d), 0.0, 20.0)
    photo_scale = minimise(lambda k: rmse((k * flat).clamp(0, 1), d), 0.0, 20.0)
    roughness = minimise(lambda c: rmse(torch.full_like(r, c), r), 0.0, 1.0)
    specular = minimise(lambda c: rmse(torch.full_like(s, c), s), 0.0, 1.0)
    chosen = {
        "mean": {"diffuse_scale": mean_scale, "roughness": roughness, "specular": specular},
        "photo": {"diffuse_scale": photo_scale, "roughness": roughness},
    }

    print("## Constants minimising each map's RMSE\n")
    for name, config in chosen.items():
        print(f"- `{name}`: " + ", ".join(f"{k} = {v}" for k, v in config.items()))
    print("\n## Scores (mean per-image RMSE; render: 6 evaluation light/view pairs, sRGB)\n")
    print("| baseline | " + " | ".join(COLUMNS) + " |")
    print("| --- |" + " ---: |" * len(COLUMNS))
    for name, config in chosen.items():
        print(row(f"{name} (these constants)", scores(name, config, photos, maps)))
    for name in chosen:
        print(row(f"{name} (registered defaults)", scores(name, {}, photos, maps)))
    print("\n## Check: what tuning on the render RMSE instead would gain\n")

    def render(name: str, cfg: dict) -> float:
        return float(render_rmse(sm.create_generator(name, cfg)(photos), maps).mean())

    grid = [
        {"diffuse_scale": mean_scale, "roughness": rr, "specular": ss}
        for rr in (0.2, 0.3, 0.4, 0.5, 0.6)
        for ss in (0.0, 0.03, 0.06, 0.1, 0.15)
    ]
    best = min(((render("mean", cfg), cfg) for cfg in grid), key=lambda item: item[0])
    print(
        f"- `mean`, diffuse scale {mean_scale}: best render RMSE {best[0]:.4f} at roughness "
        f"{best[1]['roughness']}, specular {best[1]['specular']} (grid 0.2-0.6 x 0-0.15)"
    )
    k = min(
        (render("photo", {"diffuse_scale": float(v), "roughness": roughness}), float(v))
        for v in np.round(np.linspace(0.1, 1.5, 15), 2)
    )
    print(f"- `photo`: best render RMSE {k[0]:.4f} at diffuse scale {k[1]} (grid 0.1-1.5 by 0.1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
