#!/usr/bin/env python
"""What refinement buys, per second, on materials with ground truth: the figures behind
``DEFAULT_REFINE_STEPS`` and the refinement table of docs/measured-refinement.md.

For every material of a folder of Des18-layout strips (``unseen-dev``: materials unlike any Des18
one; ``des18-dev``), the shipped model's maps (refined as the photo tools refine them,
:func:`svbrdf_models.capture.refining.refine_prediction`) and constant maps (the ``mean`` baseline,
:func:`svbrdf_render.refine_maps`) are refined at each budget, and each result is judged against
the ground truth: RMSE of each map (stored encodings) and of renderings under the 6 evaluation
views (never the photo's own view, which baking the photo into the diffuse map matches
exactly). Scores are averaged *per material* (:mod:`svbrdf_train.data.real.materials`): a Des18
strip blends two source materials (named in its file name) and counts for both; an unseen-dev
file is a material of its own. Means come
with 95% bootstrap intervals over materials, and each refined row is compared, paired, with the
network alone and with constant maps refined for the same budget.

Usage::

    .venv/bin/python benchmarks/refine_curve.py DATA/unseen-dev DATA/des18-dev --steps 0,50,150,500
    .venv/bin/python benchmarks/refine_curve.py DATA/unseen-dev --flash 15 -o refine-report

``--flash axis`` (default) finds the flash as the photo tools do (on the axis, intensity from the
start maps); ``--flash 15`` uses the known capture of unseen-dev (``Scene.flash(intensity=15)``);
``--flash fitted`` the flash fitted to each strip's *true* maps (:func:`svbrdf_render.fit_flash`),
the reference where the capture is not known (des18-dev).
Writes ``OUT/refine_curve.md`` (tables) and ``OUT/refine_curve.png`` (accuracy against seconds).
Timings are seconds per material on this machine (one material at a time, eager renderer unless
``--backend compiled``); they mean something only on an idle machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

MAPS = ("normal", "diffuse", "roughness", "specular", "render")


def score(pred, truth) -> dict[str, float]:
    from svbrdf_render.compare import map_rmse, render_rmse

    out = {k: float(v[0]) for k, v in map_rmse(pred, truth).items()}
    out["render"] = float(render_rmse(pred, truth)[0])
    return out


def _scene(flash: str, photo, truth):
    """The capture a refinement is given: none (found from the maps), a known on-axis flash, or
    the flash fitted to the true maps."""
    from svbrdf_render import Scene, fit_flash

    if flash == "axis":
        return None
    if flash == "fitted":
        return fit_flash(truth, photo).scene(0)
    return Scene.flash(intensity=float(flash))


def run_folder(folder: Path, budgets: list[int], flash: str, backend: str, model) -> dict:
    import svbrdf_models as sm
    from svbrdf_models.capture.refining import refine_prediction
    from svbrdf_render import read_des18, refine_maps
    from svbrdf_train.data.real.materials import material_groups, per_material

    mean = sm.create_generator("mean", {})
    files = sorted(folder.glob("*.png"))
    if not files:
        sys.exit(f"refine_curve: error: {folder}: no .png strips there")
    rows: dict[str, list] = {}
    seconds: dict[str, list[float]] = {}
    for i, f in enumerate(files):
        sample = read_des18(f)
        photo, truth = sample.input, sample.svbrdf
        t = time.perf_counter()
        starts = {"network": model.predict(photo[0])}
        net_seconds = time.perf_counter() - t
        starts["constant"] = mean(photo)
        scene = _scene(flash, photo, truth)
        for start_name, start in starts.items():
            for n in budgets:
                t = time.perf_counter()
                if start_name == "network" and n:  # as the photo tools refine a network's maps
                    out = refine_prediction(photo, start, n, scene=scene, backend=backend)
                else:
                    out = refine_maps(photo, start, scene=scene, steps=n, backend=backend)
                dt = time.perf_counter() - t + (net_seconds if start_name == "network" else 0.0)
                label = f"{start_name} + refine {n}" if n else f"{start_name} maps"
                rows.setdefault(label, []).append((material_groups(f), score(out.svbrdf, truth)))
                seconds.setdefault(label, []).append(dt)
        print(f"  {folder.name}: {i + 1}/{len(files)} {f.name}", file=sys.stderr, flush=True)
    return {
        label: {"materials": per_material(r).materials, "seconds": sum(seconds[label]) / len(seconds[label])}
        for label, r in rows.items()
    }


def table(name: str, results: dict, budgets: list[int]) -> str:
    from svbrdf_bench.metrics import bootstrap_ci, paired_difference

    labels = list(results)
    materials = sorted(next(iter(results.values()))["materials"])

    def values(label, k):
        return [results[label]["materials"][m][k] for m in materials]

    lines = [
        f"### {name}: {len(materials)} materials (RMSE, mean over materials [95% bootstrap])",
        "",
        "| row | s/material | " + " | ".join(MAPS) + " |",
        "|---|---|" + "---|" * len(MAPS),
    ]
    for label in labels:
        cells = []
        for k in MAPS:
            m, lo, hi = bootstrap_ci(values(label, k))
            cells.append(f"{m:.4f} [{lo:.4f}, {hi:.4f}]")
        lines.append(f"| {label} | {results[label]['seconds']:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "Paired differences (over materials), in % of the reference row:", ""]
    lines += ["| row | against | " + " | ".join(MAPS) + " |", "|---|---|" + "---|" * len(MAPS)]
    for n in budgets:
        if n == 0:
            continue
        for ref in ("network maps", f"constant + refine {n}", "constant maps"):
            label = f"network + refine {n}"
            cells = []
            for k in MAPS:
                base = sum(values(ref, k)) / len(materials)
                cells.append(paired_difference(values(label, k), values(ref, k)).percent_of(base))
            lines.append(f"| {label} | {ref} | " + " | ".join(cells) + " |")
        ref, label = "constant maps", f"constant + refine {n}"
        cells = []
        for k in MAPS:
            base = sum(values(ref, k)) / len(materials)
            cells.append(paired_difference(values(label, k), values(ref, k)).percent_of(base))
        lines.append(f"| {label} | {ref} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(all_results: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(all_results), 2, figsize=(10, 3.6 * len(all_results)), squeeze=False)
    for row, (name, results) in enumerate(all_results.items()):
        for col, k in enumerate(("render", "diffuse")):
            ax = axes[row][col]
            for start, style in (("network", "o-"), ("constant", "s--")):
                pts = [
                    (r["seconds"], sum(m[k] for m in r["materials"].values()) / len(r["materials"]))
                    for label, r in results.items()
                    if label.startswith(start)
                ]
                ax.plot([p[0] for p in pts], [p[1] for p in pts], style, label=f"{start} start")
            ax.set_xscale("symlog", linthresh=0.1)
            ax.set_xlabel("seconds per material (network + refinement)")
            ax.set_ylabel(f"{k} RMSE")
            ax.set_title(f"{name}: {k}")
            ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="folders of Des18-layout strips with ground truth")
    ap.add_argument("--steps", default="0,50,150,500", help="refinement budgets (default: 0,50,150,500)")
    ap.add_argument("--flash", default="axis", help="axis (default), a known on-axis flash intensity, or "
                    "fitted (the flash fitted to the true maps)")
    ap.add_argument("--backend", default="eager", choices=("eager", "compiled"))
    ap.add_argument("--model", default="pretrained", help="model source (default: the shipped model)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1: on a shared "
                    "2-core machine, 2 threads per process slow every process down many times)")
    ap.add_argument("-o", "--out", type=Path, default=Path("refine-report"))
    a = ap.parse_args()
    try:
        budgets = sorted({int(x) for x in a.steps.split(",")} | {0})
        if a.flash not in ("axis", "fitted"):
            float(a.flash)
    except ValueError:
        sys.exit("refine_curve: error: --steps takes integers (0,50,150); --flash axis, fitted or a number")
    if any(n < 0 for n in budgets):
        sys.exit("refine_curve: error: --steps must be >= 0")
    import svbrdf_models as sm

    torch.set_num_threads(max(1, a.threads))
    model = sm.load_model(a.model)
    a.out.mkdir(parents=True, exist_ok=True)
    all_results = {f.name: run_folder(f, budgets, a.flash, a.backend, model) for f in a.folders}
    head = (
        f"# Refinement against ground truth\n\nModel: {model.describe()}; flash: {a.flash}; "
        f"backend: {a.backend}; budgets: {budgets}; torch threads: {torch.get_num_threads()}.\n\n"
    )
    text = head + "\n".join(table(name, r, budgets) for name, r in all_results.items())
    (a.out / "refine_curve.md").write_text(text)
    plot(all_results, a.out / "refine_curve.png")
    print(text)


if __name__ == "__main__":
    main()
