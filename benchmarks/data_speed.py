#!/usr/bin/env python
"""How fast the procedural training data is made on this machine: a benchmark, not a test.

Prints Markdown tables of samples per second at 256 x 256 (``--resolution``):

1. Per family (``mix=0``) and for the default draw (all families, ``mix=0.3``):
   - *maps only, batched*: ``materials(seed, indices, R)`` in batches of ``--batch``;
   - *maps + photo, batched*: ``ProceduralMaterials.batch`` (maps, then one render per sample);
   - *maps + photo, one by one*: ``dataset[i]``.
2. Through a ``torch.utils.data.DataLoader`` (batch ``--batch``, default collate) with 0 and 2
   workers (``--workers``) over ``3 * --count`` samples, counting worker start-up; workers run
   one torch thread each and fetch whole batches through ``ProceduralMaterials.__getitems__``.
3. Made on ``--device`` (default cpu) in this process, as ``data.generate: device`` makes
   them: ``fitdata.device_batch`` (``ProceduralMaterials.batch(indices, device=...)``) in
   batches of 8 and 32, ``--device-batches`` batches each after a warm-up one (on a GPU the
   device is synchronised before the clock stops).

Timing: one warm-up batch per measurement, then ``--count`` samples (different indices every
time, so nothing is cached); samples/s = count / seconds. torch's thread count is left at its
default unless ``--threads`` says otherwise. Progress goes to stderr, the tables to stdout.

Usage::

    .venv/bin/python benchmarks/data_speed.py            # 256 x 256, 32 samples a row (~1 min)
    .venv/bin/python benchmarks/data_speed.py --quick    # smoke run (64 x 64, 8 samples)
    python benchmarks/data_speed.py --device cuda        # + batches made on the GPU
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable

import torch
from torch.utils.data import DataLoader

from svbrdf_train.data.fitdata import device_batch
from svbrdf_train.data.procedural import FAMILIES, GENERATOR_VERSION, ProceduralMaterials, materials

#: Batch sizes timed on --device: the paper's batch, and a large one.
DEVICE_BATCHES = (8, 32)


def _table(header: list[str], rows: list[list[str]]) -> str:
    align = ["---"] + ["---:"] * (len(header) - 1)
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _rate(run: Callable[[list[int]], object], start: int, count: int, batch: int) -> float:
    """Samples per second of ``run`` over ``count`` fresh indices from ``start``, in chunks of
    ``batch`` (after one warm-up chunk)."""
    run(list(range(start, start + batch)))
    start += batch
    t0 = time.perf_counter()
    for first in range(start, start + count, batch):
        run(list(range(first, min(first + batch, start + count))))
    return count / (time.perf_counter() - t0)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _device_rate(data: ProceduralMaterials, device: torch.device, batch: int, batches: int, start: int):
    """``(samples/s, ms per batch)`` of ``device_batch`` on ``device``: one warm-up batch, then
    ``batches`` batches of fresh indices."""
    device_batch(data, list(range(start, start + batch)), device)
    _sync(device)
    t0 = time.perf_counter()
    for b in range(1, batches + 1):
        device_batch(data, list(range(start + b * batch, start + (b + 1) * batch)), device)
    _sync(device)
    seconds = time.perf_counter() - t0
    return batch * batches / seconds, 1e3 * seconds / batches


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="data_speed.py",
        description=(
            "Time the procedural training data on this machine: samples per second per family, "
            "maps only and maps + photo, batched and one by one, and through a DataLoader with "
            "0 and 2 workers. Prints Markdown tables to stdout, progress to stderr."
        ),
        epilog=(
            "examples:\n"
            "  .venv/bin/python benchmarks/data_speed.py             # 256 x 256\n"
            "  .venv/bin/python benchmarks/data_speed.py --quick     # smoke run\n"
            "  .venv/bin/python benchmarks/data_speed.py --threads 1 --count 64"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--resolution", type=int, default=None, help="map size in pixels; default 256, --quick 64"
    )
    ap.add_argument(
        "--count", type=int, default=None, help="samples timed per measurement; default 32, --quick 8"
    )
    ap.add_argument("--batch", type=int, default=8, help="samples per batch (default 8, the paper's batch)")
    ap.add_argument("--workers", type=int, default=2, help="DataLoader workers of the second row (default 2)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's default)")
    ap.add_argument("--seed", type=int, default=0, help="data set seed (default 0)")
    ap.add_argument("--quick", action="store_true", help="smoke run: --resolution 64 --count 8")
    ap.add_argument(
        "--device",
        default="cpu",
        help="device the last table's batches are made on (data.generate: device): cpu, cuda, cuda:K",
    )
    ap.add_argument(
        "--device-batches",
        type=int,
        default=3,
        help="batches timed per batch size on --device, after a warm-up one (default 3)",
    )
    args = ap.parse_args(argv)
    res = args.resolution or (64 if args.quick else 256)
    count = args.count or (8 if args.quick else 32)
    if res < 2 or count < 1 or args.batch < 1 or args.workers < 1 or args.device_batches < 1:
        ap.error("--resolution, --count, --batch, --workers and --device-batches must be positive")
    try:
        device = torch.device(args.device)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        ap.error(f"--device {args.device!r}: {str(e).splitlines()[0]}")
    if args.threads:
        torch.set_num_threads(args.threads)
    threads = torch.get_num_threads()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    if load > 0.5 * (os.cpu_count() or 1):
        print(
            f"warning: 1-minute load average {load:.1f} on {os.cpu_count()} CPUs: other processes are "
            "running and the figures will be lower and noisier",
            file=sys.stderr,
            flush=True,
        )

    rows = []
    draws = [(f, [f], 0.0) for f in FAMILIES] + [("all families, mix 0.3", None, 0.3)]
    start = 0
    for label, families, mix in draws:
        data = ProceduralMaterials(10**9, res, args.seed, families=families, mix=mix)
        maps = _rate(
            lambda ix, fam=families, m=mix: materials(args.seed, ix, res, families=fam, mix=m),
            start,
            count,
            args.batch,
        )
        both = _rate(data.batch, start + 10**6, count, args.batch)
        single = _rate(lambda ix, d=data: [d[i] for i in ix], start + 2 * 10**6, count, args.batch)
        rows.append([label, f"{maps:.1f}", f"{both:.1f}", f"{single:.1f}", f"{1e3 / both:.1f}"])
        print(
            f"  {label}: maps {maps:.1f}/s, maps+photo batched {both:.1f}/s, one by one {single:.1f}/s",
            file=sys.stderr,
            flush=True,
        )
        start += 3 * 10**6

    loader_rows = []
    total = max(3 * count, 2 * args.batch * args.workers)  # enough batches to amortise start-up
    for workers in (0, args.workers):
        data = ProceduralMaterials(total, res, args.seed + 1)
        t0 = time.perf_counter()
        loader = DataLoader(data, batch_size=args.batch, num_workers=workers)
        first = None
        n = 0
        for b in loader:
            n += len(b["name"])
            if first is None:
                first = time.perf_counter() - t0
        seconds = time.perf_counter() - t0
        loader_rows.append([str(workers), str(n), f"{n / seconds:.1f}", f"{first:.2f}"])
        print(f"  DataLoader, {workers} workers: {n / seconds:.1f} samples/s", file=sys.stderr, flush=True)

    device_rows = []
    data = ProceduralMaterials(10**9, res, args.seed + 2)
    for k, batch in enumerate(DEVICE_BATCHES):
        rate, ms = _device_rate(data, device, batch, args.device_batches, k * 10**6)
        device_rows.append([str(batch), str(batch * args.device_batches), f"{rate:.1f}", f"{ms:.0f}"])
        print(f"  device_batch on {device}, batch {batch}: {rate:.1f} samples/s", file=sys.stderr, flush=True)

    print(
        f"### Procedural data speed: {res}x{res}, batches of {args.batch}, {count} samples a row "
        f"(torch {torch.__version__}, {threads} threads, {os.cpu_count()} CPUs, "
        f"{platform.processor() or platform.machine()}, generator version {GENERATOR_VERSION})\n"
    )
    print(
        _table(
            [
                "draw",
                "maps only, batched /s",
                "maps + photo, batched /s",
                "maps + photo, one by one /s",
                "ms per sample (batched, with photo)",
            ],
            rows,
        )
    )
    print(f"\n### Through a DataLoader ({res}x{res}, all families, mix 0.3, batch {args.batch})\n")
    print(_table(["workers", "samples", "samples/s (with start-up)", "first batch s"], loader_rows))
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{threads} threads"
    print(
        f"\n### Made on the device: fitdata.device_batch on {device} ({where}; {res}x{res}, all "
        f"families, mix 0.3, data.generate: device)\n"
    )
    print(_table(["batch", "samples", "samples/s", "ms per batch"], device_rows))
    if load > 0.5 * (os.cpu_count() or 1):
        print(f"\nNote: the 1-minute load average was {load:.1f} before the run (other processes).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
