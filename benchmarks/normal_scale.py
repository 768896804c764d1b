#!/usr/bin/env python
"""Do a model's normal maps beat flat ones, and what relief scale should it ship with?

For every material of a folder with ground truth, the model's normal map (network only, at
its resolution) is scored with its relief scaled by ``s`` (the generator's ``normal_scale``:
the normal's x and y scaled before normalising; 0 is flat, what the ``mean`` baseline
predicts, 1 the network's own) against the truth brought to the same size (RMSE of the stored
``(n + 1) / 2`` values, the benchmark's). Materials are grouped as the benchmark groups them
(Des18: the pair in the name; other folders: one material per file) and averaged.

It prints, per material, whether the network's own normals beat flat ones, and the scale with
the lowest mean error. Choose the scale on materials the model never trained on and that are
not the test you report: the held-out fold of a real-train fit (``--fold 1/5``), never
unseen-dev. ``--apply FILE`` then writes a copy of the model file with that scale in its
generator config (``--scale S`` to write another).

Materials: a Des18 folder, ``.h5`` shards, or a folder (or strip shard) of map-only strips,
photographed under the fixed phone capture of validation.

Usage::

    .venv/bin/python benchmarks/normal_scale.py DATA/real-train --fold 1/5 --model FIT/weights.pt
    .venv/bin/python benchmarks/normal_scale.py DATA/unseen-dev --model pretrained   # report only
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch
import torch.nn.functional as F

from svbrdf_render import encode_normal, safe_normalize

SCALES = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]


def scaled(normal: torch.Tensor, s: float) -> torch.Tensor:
    """Normals ``(B, 3, H, W)`` with z > 0, their relief scaled as the generator's ``normal_scale``."""
    xy = normal[:, :2] / normal[:, 2:3].clamp_min(1e-6)
    return safe_normalize(torch.cat([s * xy, torch.ones_like(xy[:, :1])], dim=1), dim=1)


def _rmse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((encode_normal(a) - encode_normal(b)).square().mean().sqrt())


def _materials(folder: Path, fold: str | None, resolution: int):
    """``[(material, photo (3, R, R), true normals (1, 3, R, R))]`` of the folder (its fold)."""
    from svbrdf_train.data.fitdata import Resized, open_materials
    from svbrdf_train.data.real.materials import material_groups
    from svbrdf_train.data.real.strips import MaterialStrips

    data, _ = open_materials(folder, "normal_scale")
    if fold is not None:
        if not isinstance(data, MaterialStrips):
            raise SystemExit(f"--fold needs map-only strips; {folder} holds materials with photos")
        from svbrdf_train.data.real.strips import fold_split

        _, held = fold_split(data.bank.names, fold, str(folder))
        bank = data.bank.select(held)
        data = MaterialStrips(bank, len(bank), bank.tile, seed=data.seed, photo=data.photo, augment=False)
    out = []
    for i in range(len(data)):
        s = Resized(data, resolution)[i]
        name = s["name"].removeprefix("strip:")
        groups = material_groups(name) if not isinstance(data, MaterialStrips) else (name,)
        normal = safe_normalize(s["maps"][None, 0:3], dim=1)
        out.append((groups, s["input"], normal))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="materials with ground truth (Des18 folder, shards or strips)")
    ap.add_argument(
        "--model",
        default="pretrained",
        help="model file, checkpoint or fit folder (default: the shipped model)",
    )
    ap.add_argument("--fold", help="with strips: score only the materials of this fold (k/n or names)")
    ap.add_argument("--apply", type=Path, help="write the model file with the best scale (or --scale) here")
    ap.add_argument("--scale", type=float, help="the scale --apply writes (default: the best found)")
    args = ap.parse_args(argv)
    from svbrdf_train.predict import Predictor

    torch.set_num_threads(1)
    path = Path(args.model)
    if path.is_dir():
        path = path / "weights.pt" if (path / "weights.pt").is_file() else path / "last.pt"
    model = Predictor.from_checkpoint(path) if path.exists() else Predictor.from_model(args.model)
    errors: dict[str, list[list[float]]] = {}
    for groups, photo, truth in _materials(args.folder, args.fold, model.resolution):
        with torch.no_grad():
            pred = model.predict(photo).normal
        if pred.shape[-1] != truth.shape[-1]:
            truth = safe_normalize(F.interpolate(truth, size=pred.shape[-2:], mode="area"), dim=1)
        row = [_rmse(scaled(pred, s), truth) for s in SCALES]
        for g in dict.fromkeys(groups):
            errors.setdefault(g, []).append(row)
    per = {g: [statistics.mean(r[i] for r in rows) for i in range(len(SCALES))] for g, rows in errors.items()}
    print(
        f"{model.describe()}\n{args.folder}{f' fold {args.fold}' if args.fold else ''}: {len(per)} materials"
    )
    print("| material | flat | network | best scale | at best | network beats flat |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for g, e in sorted(per.items()):
        b = min(range(len(SCALES)), key=e.__getitem__)
        print(
            f"| {g} | {e[0]:.4f} | {e[-1]:.4f} | {SCALES[b]:.1f} | {e[b]:.4f} | {'yes' if e[-1] < e[0] else 'no'} |"
        )
    means = [statistics.mean(e[i] for e in per.values()) for i in range(len(SCALES))]
    print("scale: " + ", ".join(f"{s:.1f} {m:.4f}" for s, m in zip(SCALES, means, strict=True)))
    best = min(range(len(SCALES)), key=means.__getitem__)
    wins = sum(e[-1] < e[0] for e in per.values())
    print(
        f"network's own beats flat on {wins} of {len(per)} materials; lowest mean at scale "
        f"{SCALES[best]:.1f}: {means[best]:.4f} ({100 * (means[best] / means[0] - 1):+.1f}% against flat, "
        f"{100 * (means[best] / means[-1] - 1):+.1f}% against the network's own)"
    )
    if args.apply:
        _apply(args.model, args.apply, SCALES[best] if args.scale is None else args.scale)


def _apply(source: str, out: Path, scale: float) -> None:
    """A copy of a model file with ``normal_scale`` in its generator config."""
    from svbrdf_models.modelfile.files import pretrained_path, save_model

    path = (
        pretrained_path(source.partition(":")[2] or "ours-general-cpu")
        if source.startswith("pretrained")
        else Path(source)
    )
    state = torch.load(path, map_location="cpu", weights_only=True)
    state["generator"]["config"]["normal_scale"] = float(scale)
    state.setdefault("provenance", {})["normal_scale"] = f"{scale:.2f}, chosen by benchmarks/normal_scale.py"
    sha = save_model(out, state)
    print(f"wrote {out} (normal_scale {scale:.2f}; SHA-256 {sha})")


if __name__ == "__main__":
    main()
