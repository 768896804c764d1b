#!/usr/bin/env python
"""Fits started together on a fresh MLflow store: how many runs survive, round after round.

Each round makes a new SQLite store (a path that does not exist yet), starts ``--fits`` smoke
fits on it at the same instant, waits for them, and counts a run as kept when the fit exited 0
and its run is FINISHED in the store with its metrics (``train/loss``, ``val/rmse/render``) and
its ``checkpoints/weights.pt`` artifact. MLflow creates a new store's tables without a lock; before
``svbrdf_train.tracking`` took one, two of three such fits died and once left the store
unopenable (issue 14).

Usage::

    .venv/bin/python benchmarks/concurrent_fits.py                 # 3 rounds of 3 fits
    .venv/bin/python benchmarks/concurrent_fits.py --rounds 5 --fits 4

Prints one line per round and the total (kept / started); exit status 1 if a run was lost.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _kept(client, experiment: str, outs: list[Path]) -> tuple[int, list[str]]:
    """Runs FINISHED with metrics and a checkpoint artifact; the problems of the others."""
    found = client.get_experiment_by_name(experiment)
    runs = client.search_runs([found.experiment_id]) if found else []
    problems, kept = [], 0
    for run in runs:
        missing = [m for m in ("train/loss", "val/rmse/render") if m not in run.data.metrics]
        names = {a.path for a in client.list_artifacts(run.info.run_id, "checkpoints")}
        if run.info.status != "FINISHED" or missing or "checkpoints/weights.pt" not in names:
            state = f"{run.info.status}, missing {missing or '-'}, artifacts {sorted(names)}"
            problems.append(f"run {run.info.run_id}: {state}")
        else:
            kept += 1
    if len(runs) < len(outs):
        problems.append(f"{len(outs) - len(runs)} fit(s) left no run in the store")
    return kept, problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds, each on a new store (default 3)")
    parser.add_argument("--fits", type=int, default=3, help="fits started together per round (default 3)")
    parser.add_argument("--recipe", default="no-adv", help="recipe of the smoke fits (default no-adv)")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.fits < 1:
        parser.error("--rounds and --fits must be at least 1")

    from mlflow import MlflowClient

    total_kept = total = 0
    for r in range(args.rounds):
        with tempfile.TemporaryDirectory(prefix="svbrdf-concurrent-") as tmp:
            root = Path(tmp)
            store = f"sqlite:///{root / 'new' / 'mlflow.db'}"
            env = {**os.environ, "MLFLOW_TRACKING_URI": store, "OMP_NUM_THREADS": "1"}
            outs = [root / f"fit{k}" for k in range(args.fits)]
            start = time.perf_counter()
            procs = [
                subprocess.Popen(
                    [sys.executable, "-m", "svbrdf_train", "fit", "--recipe", args.recipe, "--size", "smoke",
                     "-q", "--out", str(out), "--experiment", "together"],
                    env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                )  # fmt: skip
                for out in outs
            ]
            errors = [p.communicate()[1] for p in procs]
            failed = [
                err.strip().splitlines()[-1]
                for p, err in zip(procs, errors, strict=True)
                if p.returncode and err.strip()
            ]
            kept, problems = _kept(MlflowClient(store), "together", outs)
            total_kept += kept
            total += args.fits
            wall = time.perf_counter() - start
            print(f"round {r + 1}: {kept}/{args.fits} runs kept ({wall:.0f} s)")
            for line in failed + problems:
                print(f"  {line}")
    print(f"total: {total_kept}/{total} runs kept, {total - total_kept} lost")
    return 0 if total_kept == total else 1


if __name__ == "__main__":
    sys.exit(main())
