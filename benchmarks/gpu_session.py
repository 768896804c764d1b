#!/usr/bin/env python
"""One prepared GPU session (issue 37): how fast the paper's fit runs under each step option,
then the fastest configuration trained for the minutes left, its model file written to OUT.

Run by ``benchmarks/gpu_session.sh`` on a lent machine (it installs the packages first); on a
CPU with ``--size smoke`` it is the dry run the tests make. In order, within ``--budget``
minutes of wall time:

1. ``ours`` at ``--size`` under a ladder of step options, each added to the one before:
   batches made on the device (``data.generate: device``; the baseline), ``channels_last``,
   bf16 autocast (``train.precision``), ``torch.compile`` of the networks (``train.compile``),
   then the batch times ``--big-batch`` with the rate scaled by its square root (Adam's usual
   rule for a larger batch); each measured over ``--steps`` steps after the trainer's warm-up,
   through the real trainer (``benchmarks/train_speed.py``'s ``measure``): samples/s, and the
   share of the device's dense peak in the step's precision (``svbrdf_train.training.flops``).
2. ``no-attn`` and the ablation recipes (``--recipes``) under the fastest option set of
   ``ours``, as long as the budget allows (the rest is listed as not measured).
3. ``--train-recipe`` at ``--train-size`` (default ``cpu``: the ``small`` network, whose model
   file, 11.5 MB, can come back from the device and be shipped; a paper-size file is 420 MB)
   with that option set, for the minutes left less a margin,
   ``--no-track`` (no MLflow on the device), real strips from ``--data`` (without them
   ``ours-materials`` becomes ``ours-general``: procedural data only); the model exported to
   ``OUT/<recipe>-<size>.pt``.

Everything is written as it comes to ``OUT/gpu_session.json`` and ``OUT/gpu_session.md``, so a
session cut short still brings back what it measured.

Usage (on the device, from the repository root; OUT is the tool's result folder)::

    python benchmarks/gpu_session.py --device cuda --size paper --out "$OUT" --budget 9
    python benchmarks/gpu_session.py --device cpu --size smoke --steps 2 --budget 2 --out /tmp/dry
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: The option ladder: name, and the recipe fields it adds to the one before it.
LADDER = [
    ("device batches", {"data.generate": "device"}),
    ("+ channels_last", {"train.channels_last": True}),
    ("+ bf16", {"train.precision": "bf16"}),
    ("+ compile", {"train.compile": True}),
]


def _measure(recipe: str, size: str, steps: int, device: str, extra: dict) -> dict:
    from train_speed import measure

    from svbrdf_train.recipe import load_recipe
    from svbrdf_train.training.flops import peak_tflops, step_flops

    fields = {k: v for k, v in extra.items() if k != "data.generate"}
    r = measure(
        recipe, size, steps, device, 0, None, generate=extra.get("data.generate", "workers"), extra=fields
    )
    per_sample = step_flops(load_recipe(recipe, size, fields), device)["step"]
    peak, _ = peak_tflops(device, fields.get("train.precision", "fp32"))
    achieved = per_sample * r["samples_s"] / 1e12
    return {**r, "tflops": achieved, "share_of_peak": achieved / peak if peak else None}


def _big_batch(size: str, factor: int) -> dict:
    """The batch ``factor`` times the recipe's, the rates scaled by its square root
    (``optim.batch_rule: sqrt`` against the recipe's own batch)."""
    from svbrdf_train.recipe import load_recipe

    batch = load_recipe("ours", size).train.batch
    return {"train.batch": batch * factor, "optim.batch_rule": "sqrt", "optim.batch_reference": batch}


class Report:
    """The figures so far, rewritten to OUT after each one."""

    def __init__(self, out: Path, header: dict):
        self.out, self.data = out, {**header, "rows": [], "trained": None}
        out.mkdir(parents=True, exist_ok=True)

    def add(self, row: dict) -> None:
        self.data["rows"].append(row)
        self.write()
        share = row.get("share_of_peak")
        if "samples_s" not in row:
            print(f"{row['recipe']:<10} {row['option']:<22} not measured: {row['why']}", flush=True)
            return
        print(f"{row['recipe']:<10} {row['option']:<22} {row['samples_s']:>9.1f} samples/s"
              + (f"  {100 * share:.1f}% of peak" if share else ""), flush=True)  # fmt: skip

    def write(self) -> None:
        (self.out / "gpu_session.json").write_text(json.dumps(self.data, indent=2) + "\n")
        lines = [
            "| recipe | options | samples/s | ms/step | batch | TFLOP/s | share of peak |",
            "|---|---|---:|---:|---:|---:|---:|",
        ]
        for r in self.data["rows"]:
            if "samples_s" not in r:
                lines.append(f"| {r['recipe']} | {r['option']} | not measured: {r.get('why', '')} | | | | |")
                continue
            share = f"{100 * r['share_of_peak']:.1f}%" if r.get("share_of_peak") else "?"
            lines.append(f"| {r['recipe']} | {r['option']} | {r['samples_s']:.1f} | {r['ms_step']:.0f} | "
                         f"{r['batch']} | {r['tflops']:.2f} | {share} |")  # fmt: skip
        if self.data["trained"]:
            lines += ["", f"trained: {json.dumps(self.data['trained'])}"]
        (self.out / "gpu_session.md").write_text("\n".join(lines) + "\n")


def _ladder(args, report: Report, deadline: float) -> dict:
    """``ours`` under each option set; returns the fastest set."""
    extra: dict = {}
    best, best_rate = {}, 0.0
    steps = [(name, fields) for name, fields in LADDER] + [
        (f"+ batch x{args.big_batch}", _big_batch(args.size, args.big_batch))
    ]
    steps = steps[: args.rungs] if args.rungs else steps
    for name, fields in steps:
        extra = {**extra, **fields}
        if time.monotonic() > deadline:
            report.add({"recipe": "ours", "option": name, "why": "budget spent"})
            continue
        try:
            row = _measure("ours", args.size, args.steps, args.device, extra)
        except Exception as e:  # an option this device or torch cannot run: said, not fatal
            report.add({"recipe": "ours", "option": name, "why": f"{type(e).__name__}: {str(e)[:200]}"})
            extra = {k: v for k, v in extra.items() if k not in fields}
            continue
        report.add({**row, "option": name, "fields": extra})
        if row["samples_s"] > best_rate:
            best, best_rate = dict(extra), row["samples_s"]
    return best


def _train(args, report: Report, fields: dict, minutes: float) -> None:
    """The training recipe under ``fields`` for ``minutes``; its model file to OUT."""
    out = args.out / "fit"
    cmd = [sys.executable, "-m", "svbrdf_train", "fit", "--recipe", args.train_recipe, "--size", args.train_size,
           "--device", args.device, "--no-track", "-q", "--out", str(out), "--max-minutes", f"{minutes:.2f}", "--force"]  # fmt: skip
    if args.data:
        cmd += ["--data", args.data]
    for key, value in fields.items():
        cmd += ["--set", f"{key}={json.dumps(value) if not isinstance(value, str) else value}"]
    cmd += ["--set", "train.epochs=1000", "--set", "data.count=4000000"] if args.train_size != "smoke" else []
    t0 = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    (args.out / "fit.log").write_text(done.stdout + done.stderr)
    model = args.out / f"{args.train_recipe}-{args.train_size}.pt"
    if done.returncode == 0:
        exported = subprocess.run([sys.executable, "-m", "svbrdf_train", "export", str(out), "-o", str(model), "--force"],
                                  capture_output=True, text=True, check=False)  # fmt: skip
        (args.out / "export.log").write_text(exported.stdout + exported.stderr)
    report.data["trained"] = {"recipe": args.train_recipe, "size": args.train_size, "fields": fields, "minutes": minutes,
                              "exit": done.returncode, "wall_s": time.monotonic() - t0,
                              "model": model.name if model.is_file() else None}  # fmt: skip
    report.write()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--size", default="paper", choices=("paper", "cpu", "smoke"))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--budget", type=float, default=9.0, help="minutes of wall time for everything (default 9)"
    )
    ap.add_argument("--train-share", type=float, default=0.45, help="share of the budget kept for training")
    ap.add_argument("--steps", type=int, default=40, help="timed steps per option (after the warm-up)")
    ap.add_argument("--big-batch", type=int, default=4, help="factor of the last rung's batch (default 4)")
    ap.add_argument("--rungs", type=int, default=None, help="measure only the first N option sets (dry runs)")
    ap.add_argument(
        "--recipes",
        default="no-attn,no-attn-wide,no-adv,no-svbrdf,multigan,radn",
        help="measured under the best options",
    )
    ap.add_argument("--train-recipe", default="ours-materials", help="trained with the best options")
    ap.add_argument(
        "--train-size",
        default="cpu",
        choices=("paper", "cpu", "smoke"),
        help="size of the trained network (default cpu: a model file small enough to ship)",
    )
    ap.add_argument("--data", help="real strips for the training recipe (a strip folder or shard)")
    args = ap.parse_args(argv)
    import torch

    start = time.monotonic()
    deadline = start + args.budget * 60 * (1 - args.train_share)
    name = (
        torch.cuda.get_device_name()
        if args.device.startswith("cuda") and torch.cuda.is_available()
        else args.device
    )
    report = Report(
        args.out, {"device": name, "torch": torch.__version__, "size": args.size, "steps": args.steps}
    )
    best = _ladder(args, report, deadline)
    for recipe in [r for r in args.recipes.split(",") if r]:
        if time.monotonic() > deadline:
            report.add({"recipe": recipe, "option": "best of ours", "why": "budget spent"})
            continue
        try:
            report.add(
                {**_measure(recipe, args.size, args.steps, args.device, best), "option": "best of ours"}
            )
        except Exception as e:
            report.add(
                {"recipe": recipe, "option": "best of ours", "why": f"{type(e).__name__}: {str(e)[:200]}"}
            )
    if args.train_recipe == "ours-materials" and not args.data:
        args.train_recipe = "ours-general"  # the same network and capture, procedural data only
    left = args.budget - (time.monotonic() - start) / 60 - 1.0  # a minute for the export and the margin
    if left > 0.05:
        _train(args, report, best, left)
    print(f"wrote {args.out / 'gpu_session.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
