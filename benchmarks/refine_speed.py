#!/usr/bin/env python
"""How long refinement takes, and how much memory, at photo sizes a person captures.

For each size, a photo of a random material is refined from constant maps for the default budget
(``svbrdf_render.DEFAULT_REFINE_STEPS``) with each backend; the first compiled call of a size
compiles, so it is reported apart (``first``) from the median of the next ``--repeats`` runs.
Peak resident memory is read after each size (it only grows, so a size's figure bounds it).
On a shared machine the figures are not timings: run it idle.

Usage::

    .venv/bin/python benchmarks/refine_speed.py --sizes 256,1024 --threads 2
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import torch


def main() -> None:
    from svbrdf_render import DEFAULT_REFINE_STEPS, SVBRDF, Scene, refine_maps, render

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="256,512,1024")
    ap.add_argument("--steps", type=int, default=DEFAULT_REFINE_STEPS)
    ap.add_argument("--backends", default="compiled,eager")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--threads", type=int, default=torch.get_num_threads())
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    print(f"torch {torch.__version__}, {a.threads} threads, {a.steps} steps")
    print(f"{'size':>6} {'backend':>9} {'first s':>8} {'median s':>9} {'ms/step':>8} {'peak RSS GiB':>13}")
    g = torch.Generator().manual_seed(0)
    for size in (int(s) for s in a.sizes.split(",")):
        truth = SVBRDF(
            torch.nn.functional.normalize(torch.randn(1, 3, size, size, generator=g) * 0.2 + torch.tensor([0, 0, 1.0]).view(1, 3, 1, 1), dim=1),
            torch.rand(1, 3, size, size, generator=g),
            torch.rand(1, 1, size, size, generator=g),
            torch.rand(1, 3, size, size, generator=g) * 0.3,
        )  # fmt: skip
        photo = render(truth, Scene.flash(intensity=15.0)).clamp(0, 1)
        start = SVBRDF.constant(1, size)
        for backend in a.backends.split(","):
            times = []
            for _ in range(a.repeats + 1):
                t = time.perf_counter()
                refine_maps(photo, start, steps=a.steps, backend=backend)
                times.append(time.perf_counter() - t)
            med = statistics.median(times[1:])
            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
            print(f"{size:>6} {backend:>9} {times[0]:8.2f} {med:9.2f} {1000 * med / a.steps:8.1f} {rss:13.2f}", flush=True)


if __name__ == "__main__":
    main()
