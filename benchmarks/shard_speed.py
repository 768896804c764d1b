#!/usr/bin/env python
"""How big HDF5 shards are and how fast they read: a benchmark, not a test.

Writes the same samples into shards with several compression settings, at 8 and 16 bits,
and prints a Markdown table: KiB per sample, samples written per second, and samples read
per second through a DataLoader (batch 8) with 0 and with 2 worker processes. Reading is
the whole pipeline a training loop sees: decompression, checksum, dequantisation and
normal re-normalisation, collation.

Samples come from ``--source``:

- ``des18`` (default): centre crops of the Des18 strips in ``--folder``
  (``DATA/des18-dev``: 21 real samples, repeated to ``--count``);
- ``procedural``: ``ProceduralMaterials(count, resolution, seed=0)``.

Timing: each read is the median of ``--repeats`` full passes after one warm-up pass
(the warm-up fills the page cache, so disk speed is not measured). torch's thread count is
left at its default. Progress goes to stderr, the table to stdout.

Usage::

    .venv/bin/python benchmarks/shard_speed.py                      # des18-dev, 256 x 256
    .venv/bin/python benchmarks/shard_speed.py --source procedural --count 64
    .venv/bin/python benchmarks/shard_speed.py --only default       # the shipped setting only
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from svbrdf_train.data.shards import COMPRESSION, ShardDataset, ShardWriter

REPO = Path(__file__).resolve().parents[1]

VARIANTS = {
    "none": {},
    "lzf": {"compression": "lzf"},
    "lzf+shuffle": {"compression": "lzf", "shuffle": True},
    "gzip-1": {"compression": "gzip", "compression_opts": 1},
    "gzip-4": {"compression": "gzip", "compression_opts": 4},
    "gzip-4+shuffle": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
    "gzip-6+shuffle": {"compression": "gzip", "compression_opts": 6, "shuffle": True},
}


def _samples(args) -> list[dict]:
    if args.source == "des18":
        from svbrdf_train.data.real.des18 import Des18Folder

        folder = Des18Folder(args.folder, split="test", crop=args.resolution)
        base = [folder[i] for i in range(len(folder))]
        repeated = [base[i % len(base)] for i in range(args.count)]
        return [s | {"name": f"{s['name']}#{i}"} for i, s in enumerate(repeated)]
    from svbrdf_train.data.procedural import ProceduralMaterials

    materials = ProceduralMaterials(args.count, args.resolution, seed=0)
    samples = []
    for first in range(0, args.count, 8):
        batch = materials.batch(list(range(first, min(first + 8, args.count))))
        samples += [{k: batch[k][i] for k in ("input", "maps", "name")} for i in range(len(batch["name"]))]
    return samples


def _read_rate(path: Path, workers: int, repeats: int) -> float:
    data = ShardDataset(path)
    loader = DataLoader(data, batch_size=8, num_workers=workers, persistent_workers=workers > 0)
    times = []
    for r in range(repeats + 1):
        start = time.perf_counter()
        for _ in loader:
            pass
        if r:  # the first pass warms the page cache and starts the workers
            times.append(time.perf_counter() - start)
    return len(data) / statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--source", choices=("des18", "procedural"), default="des18")
    p.add_argument("--folder", type=Path, default=REPO.parent / "shared" / "data" / "des18-dev")
    p.add_argument("--count", type=int, default=64, help="samples per shard (default 64)")
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--only", choices=("all", "default"), default="all",
                   help="'default': only the shipped setting (shards.COMPRESSION)")
    args = p.parse_args()

    samples = _samples(args)
    variants = {"default": COMPRESSION} if args.only == "default" else VARIANTS
    print(f"# shard size and read speed: {args.source}, {args.count} samples at "
          f"{args.resolution}x{args.resolution}")
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch "
          f"{torch.__version__}, {torch.get_num_threads()} threads; shipped: {COMPRESSION}\n")
    print("| compression | bits | KiB/sample | write samples/s | read samples/s, 0 workers | 2 workers |")
    print("| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for bits in (8, 16):
            for name, compression in variants.items():
                print(f"{name} {bits}-bit ...", file=sys.stderr)
                path = Path(tmp) / f"{name}-{bits}.h5"
                start = time.perf_counter()
                with ShardWriter(path, args.resolution, bits=bits, compression=compression) as shard:
                    for i in range(0, len(samples), 8):
                        chunk = samples[i : i + 8]
                        shard.extend({
                            "input": torch.stack([s["input"] for s in chunk]),
                            "maps": torch.stack([s["maps"] for s in chunk]),
                            "name": [s["name"] for s in chunk],
                        })
                write = len(samples) / (time.perf_counter() - start)
                size = path.stat().st_size / len(samples) / 1024
                r0 = _read_rate(path, 0, args.repeats)
                r2 = _read_rate(path, 2, args.repeats)
                print(f"| {name} | {bits} | {size:.0f} | {write:.0f} | {r0:.0f} | {r2:.0f} |", flush=True)
                path.unlink()


if __name__ == "__main__":
    main()
