#!/usr/bin/env python
"""How much of the diffuse error is the albedo level: diffuse RMSE per material as it is and
after one least-squares scale per material (``sum(p * t) / sum(p * p)``), for the network's
maps and for the photo tool's refinement (100 steps), on folders of Des18-layout strips.
Linear diffuse at the strip's resolution; mean over materials [95% bootstrap].

Usage::

    .venv/bin/python benchmarks/diffuse_level.py DATA/unseen-dev DATA/des18-dev \\
        --models pretrained,pretrained:ours-materials-cpu
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch


def _rmse(p: torch.Tensor, t: torch.Tensor) -> tuple[float, float]:
    a = float((p * t).sum() / (p * p).sum().clamp_min(1e-12))
    return float((p - t).square().mean().sqrt()), float((a * p - t).square().mean().sqrt())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="folders of Des18-layout strips with ground truth")
    ap.add_argument("--models", default="pretrained", help="comma-separated model files or pretrained[:NAME]")
    ap.add_argument("--refine", type=int, default=100, help="refinement steps (default 100)")
    args = ap.parse_args(argv)
    import svbrdf_models as sm
    from svbrdf_bench.metrics import bootstrap_ci
    from svbrdf_models.capture.refining import refine_prediction
    from svbrdf_render import read_des18
    from svbrdf_train.data.real.materials import material_groups, per_material

    torch.set_num_threads(1)
    for source in args.models.split(","):
        model = sm.load_model(source)
        for folder in args.folders:
            rows = []
            for f in sorted(folder.glob("*.png")):
                sample = read_des18(f)
                photo, truth = sample.input, sample.svbrdf
                net = model.predict(photo[0])
                refined = refine_prediction(photo, net, args.refine, backend="eager").svbrdf
                t = truth.diffuse.float()
                fig = {}
                for name, maps in (("network", net.resize(*truth.size)), (f"refined {args.refine}", refined)):
                    fig[name], fig[f"{name}, scaled"] = _rmse(maps.diffuse.float(), t)
                rows.append((material_groups(f), fig))
            pm = per_material(rows)
            cells = [
                f"{k} {m:.4f} [{lo:.4f}, {hi:.4f}]"
                for k in pm.mean
                for m, lo, hi in [bootstrap_ci(pm.values(k))]
            ]
            print(f"{source}, {folder.name}: " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
