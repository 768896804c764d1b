#!/usr/bin/env python
"""Does the network's checkerboard survive refinement? One figure per photo and map.

The shipped network works at 128 px and its transposed convolutions leave a 2-pixel pattern; at
a 256 px photo that is a 4-pixel period. The figure is the *spike* at that period: the power
spectrum of the map (mean removed, channels summed) at the frequencies of a 4-pixel period
(vertical, horizontal, diagonal), over the median power of the 7x7 neighbourhood around it;
the largest of the three. A map without the pattern scores near 1 (its spectrum is smooth
there); the network's maps score 10-300.

Usage::

    .venv/bin/python benchmarks/checkerboard.py DATA/real-dev --pattern 'deschaintre*' --linear
    .venv/bin/python benchmarks/checkerboard.py DATA/real-dev --pattern 'deschaintre*' --linear \
        --model other.pt --refine 0                     # another model's network maps only

DATA/real-dev: real flash photos, 256 px (Deschaintre's linear, Luo's sRGB).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch


def spike(t: torch.Tensor, period: int) -> float:
    """Power at a ``period``-pixel pattern over the median power around it (see the module)."""
    x = t - t.mean(dim=(-2, -1), keepdim=True)
    f = torch.fft.fft2(x).abs().square().sum(0)
    h, w = f.shape
    ky, kx = h // period, w // period
    ratios = []
    for y, x0 in ((ky, 0), (0, kx), (ky, kx)):
        ys = slice(y - 3, y + 4) if y else slice(1, 4)
        xs = slice(x0 - 3, x0 + 4) if x0 else slice(1, 4)
        ratios.append(float(f[y, x0] / f[ys, xs].median()))
    return max(ratios)


def main() -> None:
    import svbrdf_models as sm
    from svbrdf_models.capture.photos import load_photo
    from svbrdf_render import DEFAULT_REFINE_STEPS

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--pattern", default="*.png")
    ap.add_argument("--linear", action="store_true", help="the photos hold linear values")
    ap.add_argument("--refine", type=int, default=DEFAULT_REFINE_STEPS, help="0: the network's maps only")
    ap.add_argument("--model", default="pretrained", help="model source (default: the shipped model)")
    a = ap.parse_args()
    model = sm.load_model(a.model)
    period = 2 * 256 // model.resolution
    rows = []
    print(f"{'photo':<40} {'normal net':>10} {'refined':>8} {'diffuse net':>11} {'refined':>8}")
    for path in sorted(a.folder.glob(a.pattern)):
        photo, _ = load_photo(path, linear=a.linear)
        if photo.shape[-1] != 256:
            photo = torch.nn.functional.interpolate(photo[None], size=(256, 256), mode="area")[0]
        net = model.predict(photo).resize(256)
        refined = model.predict(photo, refine=a.refine) if a.refine else net
        row = [spike(getattr(m, name)[0], period) for name in ("normal", "diffuse") for m in (net, refined)]
        rows.append(row)
        print(f"{path.name[:40]:<40} {row[0]:10.1f} {row[1]:8.1f} {row[2]:11.1f} {row[3]:8.1f}", flush=True)
    med = [statistics.median(r[i] for r in rows) for i in range(4)]
    print(f"{'median':<40} {med[0]:10.1f} {med[1]:8.1f} {med[2]:11.1f} {med[3]:8.1f}")


if __name__ == "__main__":
    main()
