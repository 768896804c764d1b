#!/usr/bin/env python
"""Real phone photos have no ground truth, but two failures show without it: the flash's
highlight stamped into the maps, and a dielectric called metal. A diagnostic for models,
unrefined (the network's maps alone).

For every photo of a folder (``deschaintre*`` photos are read as linear, the others as
sRGB, as DATA/real-dev's README says) and every model:

- **highlight imprint** of each map: the point under the flash is the brightest point of the
  blurred photo; the map's luminance is averaged over 12 rings around it (out to half the
  photo's width), and the imprint is the spread (standard deviation) of those ring means over
  the spread of the map itself (at least ``SPREAD_FLOOR``, 0.02: a nearly constant map, such as
  a dielectric's specular at 0.04, would otherwise turn invisible ring steps into a large
  ratio). A map that follows the material, not the flash, has ring means that barely move:
  near 0. A disc or ring of the flash stamped into the map: near 1. The same figure around
  three points half the photo away from the flash (the median of the three) is printed as
  the **floor**: what texture and large-scale shading give with no flash there. An imprint
  at its floor holds no more of the flash than the rest of the map. The same figure around
  the photo's **centre** is printed too (``centre``): a network that expects the highlight
  in the middle stamps its ring there even when the photo's highlight is elsewhere.
With ``--refine STEPS`` the maps are the photo tool's (network, then refinement against the
photo at ``--size`` pixels), so the figures say what a user of ``predict`` gets.

- **metallic**: the mean and the 95th percentile of the metallic map the glTF export would
  write (:func:`svbrdf_render.to_metal_rough`); a dielectric (paper, tiles, wood, fabric)
  should sit near 0.

It prints the figures per photo and model, their medians, and writes a contact sheet (``-o``):
one row per photo, the photo then each model's normal, diffuse, roughness, specular and
metallic maps.

Usage::

    .venv/bin/python benchmarks/real_photos.py DATA/real-dev --models pretrained,pretrained:ours-general-cpu \\
        -o docs/real-photos.png
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch
import torch.nn.functional as F

RINGS = 12
SIZE = 128
SPREAD_FLOOR = 0.02
MAPS = ("normal", "diffuse", "roughness", "specular", "metallic")
#: Offsets (rows, columns at SIZE) of the points the floor is measured around.
AWAY = ((SIZE // 2, 0), (0, SIZE // 2), (SIZE // 2, SIZE // 2))


def _luminance(x: torch.Tensor) -> torch.Tensor:
    return x.mean(dim=0) if x.shape[0] == 3 else x[0]


def flash_point(photo: torch.Tensor) -> tuple[float, float]:
    """Row and column of the brightest point of the blurred photo ``(3, H, W)``."""
    y = _luminance(photo)[None, None]
    k = max(3, y.shape[-1] // 16) | 1
    blurred = F.avg_pool2d(y, k, stride=1, padding=k // 2, count_include_pad=False)[0, 0]
    i = int(blurred.flatten().argmax())
    return i // blurred.shape[1], i % blurred.shape[1]


def imprint(image: torch.Tensor, centre: tuple[float, float]) -> float:
    """Spread of ring means around ``centre`` over the image's own spread (``(C, H, W)``)."""
    y = _luminance(image.float())
    h, w = y.shape
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    r = ((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2).sqrt()
    edges = torch.linspace(0, w / 2, RINGS + 1)
    means = [
        y[(r >= a) & (r < b)].mean()
        for a, b in zip(edges[:-1], edges[1:], strict=True)
        if bool(((r >= a) & (r < b)).any())
    ]
    return float(torch.stack(means).std()) / max(float(y.std()), SPREAD_FLOOR)


def _maps(model, photo: torch.Tensor, refine: int = 0) -> dict[str, torch.Tensor]:
    from svbrdf_render import encode_normal, to_metal_rough

    with torch.no_grad():
        m = model.predict(photo, refine=refine)
    mr = to_metal_rough(m)
    return {
        "normal": encode_normal(m.normal[0]),
        "diffuse": m.diffuse[0],
        "roughness": m.roughness[0],
        "specular": m.specular[0],
        "metallic": mr.metallic[0],
    }


def _load(path: Path, size: int) -> torch.Tensor:
    from svbrdf_models.capture.photos import load_photo

    photo, _ = load_photo(path, linear=path.name.startswith("deschaintre"))
    return F.interpolate(photo[None], size=(size, size), mode="area")[0]


def _sheet(rows: list[list[torch.Tensor]], names: list[str], out: Path) -> None:
    from svbrdf_render import linear_to_srgb, write_image

    tiles = []
    for row in rows:
        shown = [linear_to_srgb(row[0])]
        for k, t in enumerate(row[1:]):
            name = MAPS[k % len(MAPS)]
            t = t.expand(3, -1, -1) if t.shape[0] == 1 else t
            shown.append(linear_to_srgb(t) if name in ("diffuse", "specular") else t)
        gap = torch.ones(3, SIZE, 4)
        tiles.append(torch.cat([x for t in shown for x in (t, gap)], dim=2))
    sheet = torch.cat([x for t in tiles for x in (t, torch.ones(3, 4, t.shape[-1]))], dim=1)
    write_image(out, sheet.clamp(0, 1))
    print(f"wrote {out}: rows {', '.join(names)}; columns photo, then per model {' | '.join(MAPS)}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="folder of flash photos (DATA/real-dev)")
    ap.add_argument("--models", default="pretrained", help="comma-separated model files or pretrained[:NAME]")
    ap.add_argument("-o", "--out", type=Path, help="contact sheet (.png)")
    ap.add_argument("--refine", type=int, default=0, help="refinement steps after the network (default 0)")
    ap.add_argument(
        "--size", type=int, default=SIZE, help=f"side of the photo's square in pixels (default {SIZE})"
    )
    args = ap.parse_args(argv)
    from svbrdf_train.predict import Predictor

    torch.set_num_threads(1)
    sources = [s.strip() for s in args.models.split(",") if s.strip()]
    models = [
        Predictor.from_checkpoint(Path(s)) if Path(s).exists() else Predictor.from_model(s) for s in sources
    ]
    photos = sorted(p for p in args.folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    figures: dict[str, dict[str, list[float]]] = {s: {} for s in sources}
    rows = []
    print("| photo | model | " + " | ".join(f"imprint {m}" for m in MAPS) + " | metallic mean / p95 |")
    print("| --- | --- |" + " ---: |" * (len(MAPS) + 1))
    for path in photos:
        photo = _load(path, args.size)
        shown = F.interpolate(photo[None], size=(SIZE, SIZE), mode="area")[0]
        centre = flash_point(shown)
        row = [shown]
        for source, model in zip(sources, models, strict=True):
            maps = _maps(model, photo, args.refine)
            maps = {k: F.interpolate(v[None], size=(SIZE, SIZE), mode="area")[0] for k, v in maps.items()}
            imp = {m: imprint(maps[m], centre) for m in MAPS}
            away = [((centre[0] + dy) % SIZE, (centre[1] + dx) % SIZE) for dy, dx in AWAY]
            floor = {m: statistics.median(imprint(maps[m], c) for c in away) for m in MAPS}
            middle = {m: imprint(maps[m], (SIZE / 2, SIZE / 2)) for m in MAPS}
            metal = maps["metallic"].flatten()
            figs = {**{f"imprint {m}": v for m, v in imp.items()}, **{f"floor {m}": v for m, v in floor.items()},
                    **{f"centre {m}": v for m, v in middle.items()},
                    "metallic mean": float(metal.mean()),
                    "metallic p95": float(metal.quantile(0.95))}  # fmt: skip
            for k, v in figs.items():
                figures[source].setdefault(k, []).append(v)
            print(f"| {path.stem} | {source} | " + " | ".join(f"{imp[m]:.2f}" for m in MAPS)
                  + f" | {figs['metallic mean']:.2f} / {figs['metallic p95']:.2f} |")  # fmt: skip
            row += [maps[m] for m in MAPS]
        rows.append(row)
    print("\nmedians over the photos:")
    for source in sources:
        f = figures[source]
        print(f"  {source}: " + ", ".join(f"{k} {statistics.median(v):.2f}" for k, v in f.items()))
    if args.out:
        _sheet(rows, [p.stem for p in photos], args.out)


if __name__ == "__main__":
    main()
