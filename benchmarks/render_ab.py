#!/usr/bin/env python
"""Is this checkout's renderer slower than an older commit's? A/B timing: a benchmark, not a test.

Checks the older commit out into a temporary git worktree and times, in alternating rounds
(old, new, old, new...; one fresh process per round so neither inherits the other's
allocator state), the forward and backward pass of a 256 px, batch-8 render on one torch
thread: the Des18 scene on the eager backend (its hand-derived backward), the photo scene
(every image effect) on the eager backend, and the Des18 scene compiled. Prints the median
of each round and the median over rounds; a difference smaller than the spread between
rounds of one side is noise.

Usage::

    .venv/bin/python benchmarks/render_ab.py 03db3b0            # that commit against this tree
    .venv/bin/python benchmarks/render_ab.py 03db3b0 --rounds 5 --repeats 25
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Runs in a fresh process with one svbrdf-render on its path; prints "label ms" per scenario.
_ROUND = r"""
import statistics, sys, time
import torch
torch.set_num_threads(1)
from svbrdf_render import DES18_EFFECTS, PHOTO_EFFECTS, SVBRDF, Scene, render
repeats = int(sys.argv[1])
g = torch.Generator().manual_seed(0)
b, r = 8, 256
normal = torch.rand(b, 3, r, r, generator=g) * 2 - 1 + torch.tensor([0, 0, 2.0]).view(1, 3, 1, 1)
maps = SVBRDF(normal, torch.rand(b, 3, r, r, generator=g), torch.rand(b, 1, r, r, generator=g),
              torch.rand(b, 3, r, r, generator=g) * 0.3)
def once(scene, backend):
    m = SVBRDF(*(t.detach().requires_grad_(True) for t in maps.maps().values()))
    t0 = time.perf_counter()
    render(m, scene, backend=backend).sum().backward()
    return time.perf_counter() - t0
for label, effects, backend in (("des18 eager", DES18_EFFECTS, "eager"),
                                ("photo eager", PHOTO_EFFECTS, "eager"),
                                ("des18 compiled", DES18_EFFECTS, "compiled")):
    scene = Scene.flash(effects=effects)
    for _ in range(3):
        once(scene, backend)
    print(label, statistics.median(once(scene, backend) for _ in range(repeats)) * 1e3, flush=True)
"""


def _round(src: Path, repeats: int) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", _ROUND, str(repeats)], env=env, check=True,
                         capture_output=True, text=True).stdout  # fmt: skip
    return {line.rsplit(" ", 1)[0]: float(line.rsplit(" ", 1)[1]) for line in out.splitlines()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old", help="the older commit (any git revision)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds per side (default 5)")
    ap.add_argument("--repeats", type=int, default=25, help="timed renders per scenario and round")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "old"
        git = ["git", "-C", str(REPO), "worktree"]
        subprocess.run([*git, "add", "-q", "--detach", str(tree), args.old], check=True)
        try:
            src = "packages/svbrdf-render/src"
            sides = {args.old: tree / src, "this tree": REPO / src}
            times: dict[str, list[dict[str, float]]] = {side: [] for side in sides}
            for i in range(args.rounds):
                for side, src in sides.items():
                    times[side].append(_round(src, args.repeats))
                    line = ", ".join(f"{k} {v:.1f} ms" for k, v in times[side][-1].items())
                    print(f"round {i + 1}, {side}: {line}", file=sys.stderr, flush=True)
        finally:
            subprocess.run([*git, "remove", "--force", str(tree)], check=False)
    print("| scenario | " + " | ".join(sides) + " |\n| --- | ---: | ---: |")
    for label in times[args.old][0]:
        cells = []
        for side in sides:
            rounds = [r[label] for r in times[side]]
            cells.append(f"{statistics.median(rounds):.1f} ms [{min(rounds):.1f}-{max(rounds):.1f}]")
        print(f"| {label} | " + " | ".join(cells) + " |")
    print(f"\nforward+backward, 256 px, batch 8, one torch thread; median over {args.rounds} rounds of the "
          f"median of {args.repeats} renders [range of the round medians]")


if __name__ == "__main__":
    main()
