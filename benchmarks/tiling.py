#!/usr/bin/env python
"""How well do real maps tile, before and after ``make_tileable``? One table per folder.

For every Des18 strip of a folder (input | normal | diffuse | roughness | specular), each map's
``seam_error`` (svbrdf_render.tiling: RMS step across the wrap seam over the RMS step inside the
map, the worse axis; about 1 for a map that tiles) before and after ``make_tileable``, and what
the blend costs: the shift of the map's mean and its standard deviation after over before
(the contrast lost in the blend band). Medians over the strips, per map; a map without any
pixel step (a constant specular) has no seam to measure and is left out of its median
(``n`` counts the strips that remain).

Usage::

    .venv/bin/python benchmarks/tiling.py DATA/unseen-dev DATA/des18-dev
    .venv/bin/python benchmarks/tiling.py DATA/des18-dev --blend 0.5 --each

DATA/unseen-dev: 9 scanned or artist materials (256 px tiles); DATA/des18-dev: 21 Des18 test
strips (288 px tiles).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch


def main() -> None:
    from svbrdf_render import MAP_NAMES, read_des18
    from svbrdf_render.tiling import DEFAULT_BLEND, make_tileable, seam_error

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", type=Path, nargs="+", help="folders of Des18 strips (*.png)")
    ap.add_argument("--blend", type=float, default=DEFAULT_BLEND, help="band width, fraction of the side")
    ap.add_argument("--each", action="store_true", help="also print every strip's seam errors")
    a = ap.parse_args()
    for folder in a.folders:
        rows: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in MAP_NAMES}
        paths = sorted(folder.glob("*.png"))
        for path in paths:
            maps = read_des18(path).svbrdf
            tiled = make_tileable(maps, blend=a.blend)
            line = []
            for name in MAP_NAMES:
                x, y = getattr(maps, name), getattr(tiled, name)
                before, after = float(seam_error(x)[0]), float(seam_error(y)[0])
                line.append(f"{before:6.2f} ->{after:5.2f}")
                if float(x.amax() - x.amin()) == 0.0:
                    continue
                shift = float((y.mean() - x.mean()).abs())
                rows[name].append((before, after, shift, float(y.std() / x.std())))
            if a.each:
                print(f"  {path.name[:44]:<44} " + "  ".join(line))
        print(f"{folder.name}: {len(paths)} strips, blend {a.blend}")
        print(
            f"{'map':<10} {'n':>3} {'seam before':>12} {'seam after':>11} {'|mean shift|':>13}"
            f" {'std after/before':>17}"
        )
        for name, r in rows.items():
            if not r:
                print(f"{name:<10} {0:>3} {'(constant everywhere)':>42}")
                continue
            med = [statistics.median(v[i] for v in r) for i in range(4)]
            print(f"{name:<10} {len(r):>3} {med[0]:12.2f} {med[1]:11.2f} {med[2]:13.4f} {med[3]:17.3f}")


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
