"""Training throughput of the recipes through the real trainer (data, renderings, D, both optimisers).

Prints, per recipe: samples/s over the timed steps (the trainer's own figure, which leaves out its
first steps), and what a full fit of that size would take at that rate. Nothing is tracked in MLflow.

    .venv/bin/python benchmarks/train_speed.py --size cpu --steps 20
    .venv/bin/python benchmarks/train_speed.py --size paper --device cuda --steps 30 --workers 12
    .venv/bin/python benchmarks/train_speed.py --size paper --device cuda --shards train.h5 --workers 12
    .venv/bin/python benchmarks/train_speed.py --recipes ours --backends eager,compiled --clock cpu
    python benchmarks/train_speed.py --size paper --device cuda --generate device --flops \
        --set train.compile=true --set train.channels_last=true --set train.precision=bf16

``--backends`` times each recipe with each renderer of the losses (``train.render_backend``);
``--clock cpu`` counts the process's CPU time over its threads, which other programs running on
the machine do not tilt (wall time, the default here, is what a person waits on an idle machine).
``--generate device`` makes the procedural batches on the training device instead of in
DataLoader workers (``data.generate``). ``--set FIELD=VALUE`` (repeatable) sets any other recipe
field: ``train.compile``, ``train.channels_last``, ``train.precision`` are the step's options.
``--flops`` adds the model FLOPs per sample of the step (``svbrdf_train.training.flops``), the TFLOP/s
the measured rate achieves, and its share of the device's dense peak (a GPU's data-sheet TF32
or BF16 peak; on a CPU the rate of a large matmul measured on the spot).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

import torch

from svbrdf_render.formats.yamlio import safe_load
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training.clock import WARMUP_STEPS
from svbrdf_train.training.trainer import FitOptions, fit


def measure(
    name: str,
    size: str,
    steps: int,
    device: str,
    workers: int,
    shards: str | None,
    backend: str | None = None,
    clock: str = "wall",
    generate: str = "workers",
    extra: dict | None = None,
) -> dict:
    overrides = {
        **(extra or {}),
        "data.generate": generate,
        "train.clock": clock,
        "train.validate_every": 10**9,
        "train.checkpoint_every": None,
        "train.checkpoint_minutes": None,
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
    ap.add_argument("--recipes", default="ours,no-attn,no-attn-wide,no-adv,no-svbrdf,multigan,radn")
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
    ap.add_argument(
        "--generate", default="workers", choices=("workers", "device"), help="data.generate [workers]"
    )
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="any recipe field")
    ap.add_argument("--flops", action="store_true", help="model FLOPs per sample and share of the peak")
    args = ap.parse_args()
    extra = {}
    for item in args.set:
        key, _, value = item.partition("=")
        extra[key] = safe_load(value)  # YAML 1.2, as --set reads it: 3e-4 is a number
    threads = torch.get_num_threads()
    print(
        f"torch {torch.__version__}, {threads} threads, device {args.device}, size {args.size}, "
        f"clock {args.clock}, data.generate {args.generate}"
        + (f", {' '.join(args.set)}" if args.set else "")
    )
    peak = None
    if args.flops:
        from svbrdf_train.training.flops import peak_tflops

        precision = extra.get("train.precision", "fp32")
        peak, where = peak_tflops(args.device, precision)
        print(f"peak: {f'{peak:.3g} TFLOP/s' if peak else 'unknown'} ({where})")
    head = (
        f"{'recipe':<10} {'renderer':<9} {'batch':>5} {'px':>4} {'ms/step':>8} {'samples/s':>10} "
        f"{'full fit':>10}"
    )
    if args.flops:
        head += f" {'GFLOP/sample':>12} {'TFLOP/s':>8} {'of peak':>8}"
    print(head)
    backends = [b for b in args.backends.split(",") if b] or [None]
    for name in args.recipes.split(","):
        for backend in backends:
            r = measure(
                name, args.size, args.steps, args.device, args.workers, args.shards, backend, args.clock,
                args.generate, extra,
            )  # fmt: skip
            hours = r["full_fit_h"]
            full = f"{hours * 60:.1f} min" if hours < 1 else f"{hours:.1f} h"
            rate = r["samples_s"]
            line = (
                f"{name:<10} {r['backend']:<9} {r['batch']:>5} {r['res']:>4} {r['ms_step']:>8.0f} "
                f"{rate:>10.1f} {full:>10}"
            )
            if args.flops:
                line += _flops_columns(name, args.size, args.device, extra, rate, peak)
            print(line, flush=True)


def _flops_columns(name: str, size: str, device: str, extra: dict, rate: float, peak: float | None) -> str:
    from svbrdf_train.training.flops import step_flops

    per_sample = step_flops(load_recipe(name, size, extra), device)["step"]
    achieved = per_sample * rate / 1e12
    share = f"{100 * achieved / peak:.1f}%" if peak else "?"
    return f" {per_sample / 1e9:>12.1f} {achieved:>8.2f} {share:>8}"


if __name__ == "__main__":
    main()
