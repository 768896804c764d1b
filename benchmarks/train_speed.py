"""Training throughput of the recipes through the real trainer (data, renderings, D, both optimisers).

Prints, per recipe: samples/s over the timed steps (the trainer's own figure, which leaves out its
first steps), and what a full fit of that size would take at that rate. Nothing is tracked in MLflow.

    .venv/bin/python benchmarks/train_speed.py --size cpu --steps 20
    .venv/bin/python benchmarks/train_speed.py --size paper --device cuda --steps 30 --workers 12
    .venv/bin/python benchmarks/train_speed.py --size paper --device cuda --shards train.h5 --workers 12
    .venv/bin/python benchmarks/train_speed.py --recipes ours --backends eager,compiled --clock cpu

``--backends`` times each recipe with each renderer of the losses (``train.render_backend``);
``--clock cpu`` counts the process's CPU time over its threads, which other programs running on
the machine do not tilt (wall time, the default here, is what a person waits on an idle machine).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

import torch

from svbrdf_train.recipe import load_recipe
from svbrdf_train.trainer import WARMUP_STEPS, FitOptions, fit


def measure(
    name: str,
    size: str,
    steps: int,
    device: str,
    workers: int,
    shards: str | None,
    backend: str | None = None,
    clock: str = "wall",
) -> dict:
    overrides = {
        "train.clock": clock,
        "train.validate_every": 10**9,
        "train.checkpoint_every": 10**9,
        "train.log_every": 10**9,
        "data.validation": 0,
        "data.workers": workers,
    }
    if shards:
        overrides.update({"data.source": "shards", "data.path": shards})
    if backend:
        overrides["train.render_backend"] = backend
    full = load_recipe(name, size)
    recipe = load_recipe(name, size, {**overrides, "train.max_steps": WARMUP_STEPS + steps})
    backend = recipe.train.render_backend
    with tempfile.TemporaryDirectory() as tmp:
        options = FitOptions(out=Path(tmp), progress=False, track=False, device=device)
        with contextlib.redirect_stderr(io.StringIO()):  # the fit's plan lines
            result = fit(recipe, options)
    rate = result.samples_per_s
    seconds = steps * full.train.batch / rate
    total_steps = full.train.epochs * (full.data.count // full.train.batch)
    if full.train.max_steps is not None:
        total_steps = min(total_steps, full.train.max_steps)
    return {
        "recipe": name,
        "backend": backend,
        "samples_s": rate,
        "ms_step": 1000 * seconds / steps,
        "full_fit_h": total_steps * full.train.batch / rate / 3600,
        "batch": full.train.batch,
        "res": full.train.resolution,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recipes", default="ours,no-attn,no-adv,no-svbrdf,multigan,radn")
    ap.add_argument("--size", default="cpu", choices=("paper", "cpu", "smoke"))
    ap.add_argument(
        "--steps", type=int, default=20, help="timed steps per recipe (after the trainer's warm-up)"
    )
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--workers", type=int, default=0, help="DataLoader workers")
    ap.add_argument(
        "--shards", help="train from this .h5 shard (svbrdf-train data make) instead of procedural"
    )
    ap.add_argument(
        "--backends", default="", help="comma-separated train.render_backend values [the recipe's]"
    )
    ap.add_argument("--clock", default="wall", choices=("wall", "cpu"), help="what the step time counts")
    args = ap.parse_args()
    threads = torch.get_num_threads()
    print(
        f"torch {torch.__version__}, {threads} threads, device {args.device}, size {args.size}, "
        f"clock {args.clock}"
    )
    print(
        f"{'recipe':<10} {'renderer':<9} {'batch':>5} {'px':>4} {'ms/step':>8} {'samples/s':>10} "
        f"{'full fit':>10}"
    )
    backends = [b for b in args.backends.split(",") if b] or [None]
    for name in args.recipes.split(","):
        for backend in backends:
            r = measure(
                name, args.size, args.steps, args.device, args.workers, args.shards, backend, args.clock
            )
            hours = r["full_fit_h"]
            full = f"{hours * 60:.1f} min" if hours < 1 else f"{hours:.1f} h"
            rate = r["samples_s"]
            print(
                f"{name:<10} {r['backend']:<9} {r['batch']:>5} {r['res']:>4} {r['ms_step']:>8.0f} "
                f"{rate:>10.1f} {full:>10}"
            )


if __name__ == "__main__":
    main()
