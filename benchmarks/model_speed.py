#!/usr/bin/env python
"""What each registered network costs: parameters, inference and training-step time.

For every registered generator and discriminator (built-ins and installed plugins), and for
each attention module inside the paper's generator, prints a Markdown table:

* params: trainable parameters at the chosen ``--preset`` (default: the paper's size);
* inference ms: ``forward`` in eval mode under ``torch.inference_mode``, batch ``--batch``;
* train ms: forward + backward of a training step's generator part, batch ``--batch``
  (for generators: ``maps.pack().mean().backward()``; for discriminators the same on the
  logits of ``--renderings`` renderings);
* samples/s of the training step.

The attention table builds ``ours`` with each registered attention module, so it shows what
the choice of attention costs in the whole generator, which is what a user pays.

Timing: one warm-up, then the median of ``--repeats`` runs; on CUDA each run is synchronised.
``--amp bf16`` runs under autocast. Progress goes to stderr, tables to stdout.

Usage::

    .venv/bin/python benchmarks/model_speed.py                       # paper size, batch 1, CPU
    .venv/bin/python benchmarks/model_speed.py --preset small --batch 8
    python benchmarks/model_speed.py --device cuda --batch 8 --amp bf16
"""

from __future__ import annotations

import argparse
import contextlib
import platform
import statistics
import sys
import time

import torch

import svbrdf_models as sm
from svbrdf_render import SVBRDF


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _time(fn, repeats: int, device: torch.device) -> float:
    fn()  # warm-up: allocator, cuDNN algorithm choice
    _sync(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def _amp(args, device):
    if args.amp == "bf16":
        return torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _config(kind: str, name: str, preset: str | None, extra: dict | None = None) -> dict:
    cfg = dict(extra or {})
    if preset and preset in sm.describe(kind, name).presets:
        cfg["preset"] = preset
    return cfg


def _measure(module: torch.nn.Module, call, args, device) -> tuple[int, float, float]:
    """Parameters, inference ms and forward+backward ms of ``call()`` (a tensor or a list of them)."""

    def outputs():
        out = call()
        return out if isinstance(out, list) else [out]

    def infer():
        with torch.inference_mode(), _amp(args, device):
            outputs()

    def train():
        module.zero_grad(set_to_none=True)
        with _amp(args, device):
            loss = sum(o.float().mean() for o in outputs())
        loss.backward()

    module.eval()
    t_inf = _time(infer, args.repeats, device)
    module.train()
    t_train = _time(train, args.repeats, device)
    return sum(p.numel() for p in module.parameters()), t_inf, t_train


def measure_generator(name: str, args, device, extra: dict | None = None) -> tuple[int, float, float]:
    torch.manual_seed(0)
    g = sm.create("generator", name, _config("generator", name, args.preset, extra)).to(device)
    x = torch.rand(args.batch, 3, args.size, args.size, device=device)
    return _measure(g, lambda: g(x).pack(), args, device)


def measure_discriminator(name: str, args, device) -> tuple[int, float, float]:
    torch.manual_seed(0)
    d = sm.create("discriminator", name, _config("discriminator", name, args.preset)).to(device)
    n = getattr(getattr(d, "config", None), "renderings", args.renderings)
    maps = SVBRDF.constant(args.batch, args.size, device=device)
    r = torch.rand(args.batch, n, 3, args.size, args.size, device=device)
    return _measure(d, lambda: d(maps=maps, renderings=r), args, device)


def _row(label: str, source: str, params: int, t_inf: float, t_train: float, batch: int) -> str:
    return (
        f"| {label} | {source} | {params:,} | {t_inf:.1f} | {t_train:.1f} | "
        f"{batch / (t_train / 1e3):.1f} |"
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default: cpu)")
    p.add_argument("--preset", default=None, help="preset of every network that has it (default: paper size)")
    p.add_argument("--batch", type=int, default=1)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--renderings", type=int, default=9, help="renderings per sample for discriminators")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--amp", choices=["off", "bf16"], default="off")
    p.add_argument("--kind", choices=["generator", "attention", "discriminator"], action="append",
                   help="tables to print (default: all three)")
    args = p.parse_args(argv)
    device = torch.device(args.device)
    kinds = args.kind or ["generator", "attention", "discriminator"]

    where = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "CPU"
    print(f"device: {where}; torch {torch.__version__}; threads {torch.get_num_threads()}; "
          f"batch {args.batch}; {args.size}x{args.size}; preset {args.preset or 'paper'}; amp {args.amp}\n")
    header = (
        "| {} | source | params | inference ms | train ms | train samples/s |\n"
        "| --- | --- | ---: | ---: | ---: | ---: |"
    )
    reg = sm.default_registry()
    if "generator" in kinds:
        print(header.format("generator"))
        for name in sm.list_models("generator"):
            print(f"timing generator {name}", file=sys.stderr)
            print(_row(name, ", ".join(reg.sources("generator", name)),
                       *measure_generator(name, args, device), args.batch), flush=True)
        print()
    if "attention" in kinds:
        print(header.format("ours with attention"))
        for name in sm.list_models("attention"):
            print(f"timing ours + {name}", file=sys.stderr)
            print(_row(name, ", ".join(reg.sources("attention", name)),
                       *measure_generator("ours", args, device, {"attention": name}), args.batch), flush=True)
        print()
    if "discriminator" in kinds:
        print(header.format("discriminator"))
        for name in sm.list_models("discriminator"):
            print(f"timing discriminator {name}", file=sys.stderr)
            print(_row(name, ", ".join(reg.sources("discriminator", name)),
                       *measure_discriminator(name, args, device), args.batch), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
