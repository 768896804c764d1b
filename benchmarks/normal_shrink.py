#!/usr/bin/env python
"""Do a model's normal maps carry anything that transfers? A diagnostic: a benchmark, not a test.

For every strip of a Des18-layout folder, the model's normal map (network only, at its
resolution) is blended toward flat normals, ``normalise(flat + alpha (n - flat))`` for alpha
from 0 (flat, what the `mean` baseline predicts) to 1 (the network's own), and scored against
the ground truth resized the same way (RMSE of the stored ``(n + 1) / 2`` values). Strips are
grouped by the name's material field (Des18: the pair of source materials; other folders: one
group per file) and the groups averaged. If the lowest error sits near alpha 0, the predicted
relief is mostly noise: shrinking it can only reach the flat baseline, not beat it.

Choose alpha on a folder the model never trained on and that is not the test you report
(for the shipped model: des18-dev, never unseen-dev).

Usage::

    .venv/bin/python benchmarks/normal_shrink.py DATA/des18-dev
    .venv/bin/python benchmarks/normal_shrink.py DATA/des18-dev --model pretrained:ours-mix-cpu
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch
import torch.nn.functional as F

import svbrdf_models as sm
from svbrdf_render import encode_normal, read_des18, safe_normalize

ALPHAS = [i / 10 for i in range(11)]


def _resize(t: torch.Tensor, size: int) -> torch.Tensor:
    return F.interpolate(t, size=(size, size), mode="bilinear", antialias=True, align_corners=False)


def _group(path: Path) -> str:
    parts = path.stem.split(";")
    return parts[1] if len(parts) == 3 else path.stem


def strip_errors(model, path: Path) -> list[float]:
    """The normal RMSE of one strip for each alpha of :data:`ALPHAS`."""
    sample = read_des18(path)
    r = model.resolution
    truth = safe_normalize(_resize(sample.svbrdf.normal, r), dim=1)
    with torch.no_grad():
        pred = model.predict(_resize(sample.input, r)[0]).normal
    flat = torch.zeros_like(pred)
    flat[:, 2] = 1
    out = []
    for a in ALPHAS:
        n = safe_normalize(flat + a * (pred - flat), dim=1)
        out.append(float((encode_normal(n) - encode_normal(truth)).square().mean().sqrt()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="Des18-layout strips with ground truth")
    ap.add_argument("--model", default="pretrained", help="model source (default: the shipped model)")
    args = ap.parse_args()
    model = sm.load_model(args.model)
    groups: dict[str, list[list[float]]] = {}
    for path in sorted(args.folder.glob("*.png")):
        groups.setdefault(_group(path), []).append(strip_errors(model, path))
    means = [
        statistics.mean(statistics.mean(e[i] for e in g) for g in groups.values()) for i in range(len(ALPHAS))
    ]
    print(f"{model.describe()}\n{args.folder}: {len(groups)} groups; normal RMSE, mean over groups")
    for a, m in zip(ALPHAS, means, strict=True):
        label = " (flat normals)" if a == 0 else " (the network's own)" if a == 1 else ""
        print(f"  alpha {a:.1f}: {m:.4f}{label}")
    best = min(range(len(ALPHAS)), key=means.__getitem__)
    change = 100 * (means[best] / means[0] - 1)
    print(f"lowest at alpha {ALPHAS[best]:.1f}: {means[best]:.4f}, {change:+.1f}% against flat")


if __name__ == "__main__":
    main()
