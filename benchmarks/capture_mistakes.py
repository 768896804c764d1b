#!/usr/bin/env python
"""What each capture mistake costs: the figures of docs/capture-guide.md.

For every material of a folder with ground truth (DATA/unseen-dev: materials no training set
here shows), photos are rendered by svbrdf-render under a good capture and under common
mistakes, each the good capture with one thing changed:

=====================  ==============================================================
good                   flash on the camera at 2.2 patch half-widths, intensity 15
                       (unseen-dev's own capture), linear, clipped at 1
too close              the phone at 1.3 (the highlight covers much of the patch)
too far                the phone at 4.5 (weak, flat light: little shading to read)
overexposed            4x the exposure: the highlight and more clip to white
underexposed           1/8 the exposure, and the read noise of a dark photo
other light on         a ceiling light (a second point light far above, off to the
                       side, half the flash's irradiance at the patch)
off-centre             the phone shifted by 0.6 half-widths: the highlight near an edge
=====================  ==============================================================

Each photo goes through the default capture of ``svbrdf-models predict`` (the shipped model,
then ``--refine`` steps, 100 by default; ``--refine 0`` for the network alone), and the maps
are scored against the truth (RMSE of each map and of renderings under the 6 evaluation
views), averaged over materials, with the change against the good capture.

Usage::

    .venv/bin/python benchmarks/capture_mistakes.py DATA/unseen-dev
    .venv/bin/python benchmarks/capture_mistakes.py DATA/unseen-dev --refine 0 --model pretrained:ours-mix-cpu
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch

MAPS = ("normal", "diffuse", "roughness", "specular", "render")


def _scene(distance=2.2, intensity=15.0, shift=0.0, ceiling=False):
    from svbrdf_render import DES18_EFFECTS, Camera, PointLight, Scene

    position = torch.tensor([shift, 0.0, distance])
    lights = [PointLight(position, intensity)]
    if ceiling:  # far above, off to the side: half the flash's irradiance at the centre
        far = torch.tensor([3.0, 2.0, 8.0])
        lights.append(PointLight(far, 0.5 * intensity / distance**2 * float(far.square().sum())))
    return Scene(Camera(position), tuple(lights), DES18_EFFECTS)


def _photo(maps, scene, gain=1.0, noise=0.0, seed=0):
    from svbrdf_render import render

    x = render(maps, scene)
    x = x[:, 0] if x.dim() == 5 else x
    x = x * gain
    if noise:
        g = torch.Generator().manual_seed(seed)
        x = x + noise * torch.randn(x.shape, generator=g)
    return x.clamp(0, 1)


CAPTURES = {
    "good": lambda m: _photo(m, _scene()),
    "too close (1.3)": lambda m: _photo(m, _scene(distance=1.3, intensity=15.0 * (1.3 / 2.2) ** 2)),
    "too far (4.5)": lambda m: _photo(m, _scene(distance=4.5, intensity=15.0 * (4.5 / 2.2) ** 2)),
    "overexposed (x4)": lambda m: _photo(m, _scene(), gain=4.0),
    "underexposed (/8, noisy)": lambda m: _photo(m, _scene(), gain=1 / 8, noise=0.004),
    "other light on": lambda m: _photo(m, _scene(ceiling=True)),
    "off-centre (0.6)": lambda m: _photo(m, _scene(shift=0.6)),
}


def _score(pred, truth) -> dict[str, float]:
    from svbrdf_render.compare import map_rmse, render_rmse

    out = {k: float(v[0]) for k, v in map_rmse(pred, truth).items()}
    out["render"] = float(render_rmse(pred, truth)[0])
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="materials with ground truth (DATA/unseen-dev)")
    ap.add_argument("--model", default="pretrained", help="model source (default: the shipped model)")
    ap.add_argument("--refine", type=int, default=100, help="refinement steps (default 100, as predict)")
    args = ap.parse_args(argv)
    import svbrdf_models as sm
    from svbrdf_render import read_des18

    torch.set_num_threads(1)
    model = sm.load_model(args.model)
    scores: dict[str, list[dict[str, float]]] = {name: [] for name in CAPTURES}
    for path in sorted(args.folder.glob("*.png")):
        truth = read_des18(path).svbrdf
        for name, capture in CAPTURES.items():
            photo = capture(truth)
            pred = model.predict(photo[0], refine=args.refine, backend="eager")
            scores[name].append(
                _score(pred.resize(truth.size[0]) if pred.size != truth.size else pred, truth)
            )
    means = {n: {k: statistics.mean(s[k] for s in rows) for k in MAPS} for n, rows in scores.items()}
    good = means["good"]
    print(f"{model.describe()}, refine {args.refine}; {args.folder}: {len(scores['good'])} materials")
    print("| capture | " + " | ".join(MAPS) + " |")
    print("| --- |" + " ---: |" * len(MAPS))
    for name, m in means.items():
        cells = [
            f"{m[k]:.4f}" + ("" if name == "good" else f" ({100 * (m[k] / good[k] - 1):+.0f}%)") for k in MAPS
        ]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
