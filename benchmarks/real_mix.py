#!/usr/bin/env python
"""Which training data teaches real materials: procedural only, real only, a mix, or procedural
then fine-tuned on real, under one CPU-time budget, judged on real strips none of them saw.

The strips of a Des18 folder (with ground truth) are split in two folds by their sorted position:
even positions train, odd ones judge (``--swap``: the other way round). Then four fits of the
same model (``ours`` at the ``--size``, default ``cpu``) each get ``--minutes`` of training on
the fit's clock (process CPU time over its threads):

====  ====================  ===============================================================
(a)   ``ours``              procedural materials only (``data.count`` 20000)
(b)   ``ours-real``         the training fold only (every strip trains: ``validation`` 0)
(c)   ``ours-mix``          procedural and the training fold, half and half
(d)   ``ours-finetune``     (a) stopped at ``--pretrain`` of the budget, then ``--init`` from it
                            on the training fold for the rest of the budget
====  ====================  ===============================================================

(a) is one fit: it writes its checkpoint when the pre-training share is reached, (d) starts
from a copy, and (a) resumes to the whole budget (a resumed fit is bitwise the one that never
stopped). Every fit watches the judging fold as ``val_real/`` (never used to choose weights:
the last checkpoint is judged). Then ``svbrdf-bench run --from-runs`` scores the four and the
``mean`` and ``photo`` baselines on the judging fold: RMSE per map and on renderings with
bootstrap intervals, and each model against ``mean``.

Usage::

    .venv/bin/python benchmarks/real_mix.py ../shared/data/des18-dev -o real-mix   # 4 x 30 min
    .venv/bin/python benchmarks/real_mix.py DIR --jobs 2 --threads 1                # two at a time
    .venv/bin/python benchmarks/real_mix.py DIR --size smoke --minutes 0.1          # a dry run, seconds
    .venv/bin/python benchmarks/real_mix.py DIR --print                             # the commands only

Runs go to MLflow (``MLFLOW_TRACKING_URI``, else ``./mlflow.db``), experiment ``real-mix``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

COMMON = (
    *("--set", "train.epochs=100000"),
    *("--set", "train.validate_every=500", "--set", "train.checkpoint_every=500"),
)


@dataclass
class Job:
    name: str
    args: list[str]
    after: str | None = None
    then: list[Job] = field(default_factory=list)  # started when this one ends


def strips(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png" and not p.name.startswith("."))


def make_folds(data: Path, out: Path, swap: bool) -> tuple[Path, Path, int, int]:
    files = strips(data)
    if len(files) < 4:
        sys.exit(f"real_mix: error: {data}: {len(files)} Des18 strips; two folds need at least 4")
    even, odd = files[0::2], files[1::2]
    train, judge = (odd, even) if swap else (even, odd)
    folders = []
    for name, part in (("train", train), ("judge", judge)):
        folder = out / "folds" / name
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        for f in part:
            (folder / f.name).symlink_to(f.resolve())
        folders.append(folder)
    return folders[0], folders[1], len(train), len(judge)


def fit_args(
    recipe: str, size: str, run: str, out: Path, minutes: float, judge: Path, *extra: str
) -> list[str]:
    return [
        sys.executable, "-m", "svbrdf_train", "fit", "--recipe", recipe, "--size", size, "-q",
        "--experiment", "real-mix", "--run-name", run, "--out", str(out), "--force",
        "--max-minutes", f"{minutes:g}", "--set", f"data.real_validation={judge}", *COMMON, *extra,
    ]  # fmt: skip


def plan(args, train: Path, judge: Path) -> tuple[list[Job], Callable[[], None]]:
    out, size, m = args.out, args.size, args.minutes
    pre = m * args.pretrain
    real = ("--data", str(train), "--set", "data.validation=0")
    mix = "[{source: procedural, weight: 0.5}, {source: des18, weight: 0.5, validation: 0}]"
    pre_ckpt = out / "fits" / "d-pretrained"

    def copy():
        pre_ckpt.mkdir(parents=True, exist_ok=True)
        for name in ("last.pt", "last.json"):
            shutil.copy2(out / "fits" / "a" / name, pre_ckpt / name)

    resume_a = Job(
        "a (resumed)",
        [sys.executable, "-m", "svbrdf_train", "fit", "--resume", "--out", str(out / "fits" / "a"),
         "--max-minutes", f"{m:g}", "-q"],
    )  # fmt: skip
    finetune = Job(
        "d",
        fit_args("ours-finetune", size, "d-finetune", out / "fits" / "d", m - pre, judge, *real,
                 "--init", str(pre_ckpt)),
    )  # fmt: skip
    return [
        Job(
            "a (pre-training)",
            fit_args(
                "ours", size, "a-procedural", out / "fits" / "a", pre, judge, "--set", "data.count=20000"
            ),
            then=[resume_a, finetune],
        ),
        Job("b", fit_args("ours-real", size, "b-real", out / "fits" / "b", m, judge, *real)),
        Job(
            "c",
            fit_args("ours-mix", size, "c-mix", out / "fits" / "c", m, judge, "--data", str(train),
                     "--set", "data.count=20000", "--set", f"data.mix={mix}"),
        ),  # fmt: skip
    ], copy


def run_jobs(jobs: list[Job], copy, parallel: int, env: dict) -> None:
    queue = list(jobs)
    running: list[tuple[Job, subprocess.Popen, float]] = []
    logs = {}
    while queue or running:
        while queue and len(running) < parallel:
            job = queue.pop(0)
            log = open(Path(job.args[job.args.index("--out") + 1]).with_suffix(".log"), "a")  # noqa: SIM115
            logs[job.name] = log
            print(f"[{time.strftime('%H:%M:%S')}] start {job.name}: {' '.join(job.args[1:])}", flush=True)
            running.append((job, subprocess.Popen(job.args, env=env, stdout=log, stderr=log), time.time()))
        time.sleep(2)
        for item in list(running):
            job, proc, start = item
            if proc.poll() is None:
                continue
            running.remove(item)
            logs[job.name].close()
            took = (time.time() - start) / 60
            print(f"[{time.strftime('%H:%M:%S')}] {job.name} ended (exit {proc.returncode}, {took:.1f} min)")
            if proc.returncode != 0:
                sys.exit(f"real_mix: error: fit {job.name} failed; its log: {logs[job.name].name}")
            if job.then:
                copy()
                queue = job.then + queue


def run_ids(out: Path) -> list[str]:
    import json

    ids = []
    for name in ("a", "b", "c", "d"):
        summary = json.loads((out / "fits" / name / "last.json").read_text())
        ids.append(summary["run_id"])
    return ids


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("data", type=Path, help="a Des18 folder of strips with ground truth (e.g. des18-dev)")
    p.add_argument("-o", "--out", type=Path, default=Path("real-mix"), help="folds, fits and the report")
    p.add_argument("--minutes", type=float, default=30.0, help="training budget per variant (default 30)")
    p.add_argument("--pretrain", type=float, default=2 / 3, help="share of (d)'s budget on procedural data")
    p.add_argument("--size", default="cpu", choices=("cpu", "smoke", "paper"))
    p.add_argument("--jobs", type=int, default=1, help="fits at a time (each gets --threads threads)")
    p.add_argument("--threads", type=int, default=None, help="torch threads per fit (default: torch's)")
    p.add_argument("--swap", action="store_true", help="train on the odd strips, judge on the even ones")
    p.add_argument("--print", dest="show", action="store_true", help="print the commands, run nothing")
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(f"real_mix: error: {args.data}: not a folder; give a Des18 folder of strips", file=sys.stderr)
        return 2
    if not 0 < args.pretrain < 1 or args.minutes <= 0 or args.jobs < 1:
        print("real_mix: error: --pretrain must be in (0, 1), --minutes and --jobs positive", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    train, judge, n_train, n_judge = make_folds(args.data, args.out, args.swap)
    print(f"folds: {n_train} strips train ({train}), {n_judge} judge ({judge})")
    jobs, copy = plan(args, train, judge)
    if args.show:
        for job in jobs:
            for j in (job, *job.then):
                print(f"{j.name}: {' '.join(j.args[1:])}")
        return 0
    env = dict(os.environ)
    if args.threads:
        env["OMP_NUM_THREADS"] = str(args.threads)
    (args.out / "fits").mkdir(exist_ok=True)
    # Fits starting together on a new SQLite store race to create its tables: create them first.
    store = "import mlflow; mlflow.MlflowClient().search_experiments()"
    subprocess.run([sys.executable, "-c", store], env=env, check=True, capture_output=True)
    run_jobs(jobs, copy, args.jobs, env)
    ids = run_ids(args.out)
    bench = [
        sys.executable, "-m", "svbrdf_bench", "run", "--from-runs", ",".join(ids), "--test-data", str(judge),
        "--experiment", "real-mix", "-o", str(args.out / "report"),
    ]  # fmt: skip
    print(f"[{time.strftime('%H:%M:%S')}] judging: {' '.join(bench[1:])}", flush=True)
    return subprocess.run(bench, env=env).returncode


if __name__ == "__main__":
    sys.exit(main())
