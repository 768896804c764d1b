#!/usr/bin/env python
"""What a grey card in the photo buys (issue 44, part 1): per map and render RMSE of the
capture (network + refinement) on the material's pixels, for photos of materials with ground
truth under a flash of unknown exposure, five ways:

- ``no card``: the photo of the material alone, flash estimated (the default capture);
- ``known flash``: the same photo refined under the true flash (what measuring could reach);
- ``card, unused``: an 18% grey card in a corner of the photo, not given (``--reference`` off);
- ``card, guessed place``: ``--reference`` on the card (the network shown the photo with the
  card filled in from the material around it), camera and flash guessed over the
  photo's highlight at the Des18 distance (a photo without EXIF);
- ``card, known place``: ``--reference`` on the card, camera and flash where they were (what
  EXIF, ``--distance`` or the printed frame give).

Each strip's material is photographed under a co-located flash at distance 2.2 on the axis,
intensity 15 times an exposure drawn per strip in [0.5, 2] (log-uniform, seeded), clipped to
[0, 1], linear. The card covers rows and columns 8-64 of 256 (a 5% corner). Everything is
scored on the material's pixels only (the card's square left out of every row), at 256 px:
maps on their stored encodings, renderings under the 6 evaluation light/view pairs as a
screen shows them. Mean over materials [95% bootstrap]; the constant-map baseline ``mean``
(constant maps from the plain photo's statistics) is printed beside them.

Usage::

    .venv/bin/python benchmarks/reference_card.py DATA/unseen-dev DATA/des18-dev [--refine 100]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch

CARD = (8, 8, 64, 64)  # top, left, bottom, right in 256 px
ROUTES = ("no card", "known flash", "card, unused", "card, guessed place", "card, known place")
MAPS = ("normal", "diffuse", "roughness", "specular", "render")


def _masked_rmse(a: torch.Tensor, b: torch.Tensor, keep: torch.Tensor) -> float:
    """RMSE of ``a`` against ``b`` (..., C, H, W) over the pixels where ``keep`` (H, W) is true."""
    d = (a - b).square()
    return float(d[..., keep].mean().sqrt())


def _scores(pred, truth, keep) -> dict[str, float]:
    from svbrdf_render import MAP_NAMES, evaluation_scene, stored_value
    from svbrdf_render.compare import display_rendering

    out = {n: _masked_rmse(stored_value(n, getattr(pred, n)), stored_value(n, getattr(truth, n)), keep) for n in MAP_NAMES}
    scene = evaluation_scene()
    out["render"] = _masked_rmse(display_rendering(pred, scene), display_rendering(truth, scene), keep)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="folders of Des18-layout strips with ground truth")
    ap.add_argument("--model", default="pretrained", help="model file or pretrained[:NAME] (default: pretrained)")
    ap.add_argument("--refine", type=int, default=100, help="refinement steps (default 100)")
    ap.add_argument("--albedo", type=float, default=0.18, help="the card's albedo (default 0.18)")
    args = ap.parse_args(argv)
    import svbrdf_models as sm
    from svbrdf_bench.metrics import bootstrap_ci
    from svbrdf_models.capture.reference import Reference, fill_card, pin_flash
    from svbrdf_models.capture.refining import refine_prediction
    from svbrdf_render import SVBRDF, Scene, read_des18, render
    from svbrdf_render.refinement.fit import card_maps
    from svbrdf_train.data.real.materials import material_groups, per_material

    torch.set_num_threads(1)
    model = sm.load_model(args.model)
    baseline = sm.create_generator("mean")
    t, l, b, r = CARD
    ref = Reference(l, t, r - l, b - t, args.albedo)
    for folder in args.folders:
        rows = []
        files = sorted(folder.glob("*.png"))
        for i, f in enumerate(files):
            truth = read_des18(f).svbrdf.resize(256, 256)
            g = torch.Generator().manual_seed(1000 + i)
            exposure = math.exp(math.log(0.5) + math.log(4.0) * float(torch.rand((), generator=g)))
            scene = Scene.flash(2.2, 15.0 * exposure)
            mask = torch.zeros(1, 1, 256, 256, dtype=torch.bool)
            mask[..., t:b, l:r] = True
            card = card_maps(args.albedo, (256, 256))
            carded = SVBRDF(*(torch.where(mask, getattr(card, n), x) for n, x in truth.maps().items()), validate=False)
            plain = render(truth, scene).clamp(0, 1)
            with_card = render(carded, scene).clamp(0, 1)
            keep = ~mask[0, 0]
            fig = {}
            net = model.predict(plain[0])
            fig["no card"] = refine_prediction(plain, net, args.refine, backend="eager").svbrdf
            fig["known flash"] = refine_prediction(plain, net, args.refine, scene=scene, backend="eager").svbrdf
            net_card = model.predict(with_card[0])
            fig["card, unused"] = refine_prediction(with_card, net_card, args.refine, backend="eager").svbrdf
            net_filled = model.predict(fill_card(with_card[0], mask))  # the network is not shown the card
            for name, position in (("card, guessed place", None), ("card, known place", torch.tensor([0.0, 0.0, 2.2]))):
                pinned = pin_flash(with_card[0], net_filled, ref, (0, 0, 256, 256, 256), f.name, position=position)
                fig[name] = refine_prediction(
                    with_card, pinned.start(net_filled), args.refine, scene=pinned.scene, backend="eager",
                    held=(pinned.mask, pinned.card),
                ).svbrdf
            scores = {route: _scores(maps, truth, keep) for route, maps in fig.items()}
            with torch.no_grad():
                scores["mean (baseline)"] = _scores(baseline(plain), truth, keep)
            flat = {f"{route}|{m}": v for route, s in scores.items() for m, v in s.items()}
            rows.append((material_groups(f), flat))
            print(f"  {f.name[:48]:48s} exposure x{exposure:.2f}: "
                  + ", ".join(f"{route} diffuse {s['diffuse']:.3f} render {s['render']:.3f}" for route, s in scores.items()),
                  flush=True)  # fmt: skip
        pm = per_material(rows)
        print(f"\n{folder.name}: {len(files)} strips; RMSE on the material's pixels, mean over materials "
              f"[95% bootstrap]; exposure x0.5-2, refine {args.refine}")  # fmt: skip
        print("| route | " + " | ".join(MAPS) + " |")
        print("| --- |" + " ---: |" * len(MAPS))
        for route in (*ROUTES, "mean (baseline)"):
            cells = []
            for m in MAPS:
                mean, lo, hi = bootstrap_ci(pm.values(f"{route}|{m}"))
                cells.append(f"{mean:.4f} [{lo:.4f}, {hi:.4f}]")
            print(f"| {route} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
