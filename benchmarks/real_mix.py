#!/usr/bin/env python
"""Which training data teaches real materials: procedural only, real only, a mix, or procedural
then fine-tuned on real, under one CPU-time budget, judged on real strips none of them saw.

The strips of a Des18 folder (with ground truth) are split in two folds by their sorted
position. Fold 0 trains on the even positions and is judged on the odd ones; fold 1 the other
way round, so every strip is judged once, by models that never trained on it. The same model
(``ours`` at ``--size``, default ``cpu``) is trained four ways, each for ``--minutes`` on the
fit's clock (process CPU time over its threads):

====  ====================  ===============================================================
(a)   ``ours``              procedural materials only (``data.count`` 20000); one fit serves
                            both folds, since it never sees a real strip
(b)   ``ours-real``         the fold's training strips only (all of them: ``validation`` 0)
(c)   ``ours-mix``          procedural and the fold's training strips, half and half
(d)   ``ours-finetune``     (a) stopped at ``--pretrain`` of the budget, then ``--init`` from
                            it on the fold's training strips for the rest of the budget
====  ====================  ===============================================================

(a) writes its checkpoint when the pre-training share is reached; (d) starts from a copy and
(a) resumes to the whole budget (a resumed fit is bitwise the one that never stopped). Every fit
watches a judging fold as ``val_real/`` (fold 0's for (a)); the last checkpoint is judged, never
one chosen on it. Judging: ``svbrdf-bench run --from-runs`` per fold (the full report, with the
``mean`` and ``photo`` baselines, in ``OUT/report-fold0`` and ``OUT/report-fold1``), then all
strips together: per-image RMSE of each map and of the renderings, pooled over the two folds,
with 95% bootstrap intervals and the paired difference against ``mean`` (``OUT/pooled.md``).

These folds split *strips*, not materials: every Des18 strip blends two of the same four
source materials, so the judging strips show materials each fit trained on, and the figures
flatter the fits with real strips. ``benchmarks/generalisation.py`` judges by material folds
(``svbrdf_train.data.real.materials``) and on materials no strip shows.

Usage::

    .venv/bin/python benchmarks/real_mix.py DATA/des18-dev -o real-mix --jobs 2 --threads 1
    .venv/bin/python benchmarks/real_mix.py DIR --size smoke --minutes 0.1     # the pipeline, in a minute
    .venv/bin/python benchmarks/real_mix.py DIR --print                        # the commands only
    .venv/bin/python benchmarks/real_mix.py DIR -o real-mix --judge-only       # judge the fits in OUT/fits

Runs go to MLflow (``MLFLOW_TRACKING_URI``, else ``./mlflow.db``), experiment ``real-mix``.
"""

from __future__ import annotations

import argparse
import json
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
VARIANTS = ("a", "b", "c", "d")
LABELS = {
    "a": "(a) procedural",
    "b": "(b) real only",
    "c": "(c) mix",
    "d": "(d) procedural, then real",
}
#: The recipe of each variant: its row label in the benchmark's report.
RECIPES = {"a": "ours", "b": "ours-real", "c": "ours-mix", "d": "ours-finetune"}
COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")


@dataclass
class Job:
    name: str
    args: list[str]
    then: list[Job] = field(default_factory=list)  # started when this one ends


def strips(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png" and not p.name.startswith("."))


def make_folds(data: Path, out: Path) -> list[tuple[Path, Path]]:
    """``[(train, judge)]`` of folds 0 and 1: folders of links to the strips."""
    files = strips(data)
    if len(files) < 4:
        sys.exit(f"real_mix: error: {data}: {len(files)} Des18 strips; two folds need at least 4")
    halves = (files[0::2], files[1::2])
    folds = []
    for k in (0, 1):
        pair = []
        for role, part in (("train", halves[k]), ("judge", halves[1 - k])):
            folder = out / "folds" / f"fold{k}" / role
            if folder.exists():
                shutil.rmtree(folder)
            folder.mkdir(parents=True)
            for f in part:
                (folder / f.name).symlink_to(f.resolve())
            pair.append(folder)
        folds.append((pair[0], pair[1]))
    return folds


def fit_args(
    recipe: str, size: str, run: str, out: Path, minutes: float, judge: Path, *extra: str
) -> list[str]:
    return [
        sys.executable, "-m", "svbrdf_train", "fit", "--recipe", recipe, "--size", size, "-q",
        "--experiment", "real-mix", "--run-name", run, "--out", str(out), "--force",
        "--max-minutes", f"{minutes:g}", "--set", f"data.real_validation={judge}", *COMMON, *extra,
    ]  # fmt: skip


def fit_folder(out: Path, variant: str, fold: int) -> Path:
    return out / "fits" / ("a" if variant == "a" else f"fold{fold}/{variant}")


def plan(args, folds: list[tuple[Path, Path]]) -> tuple[list[Job], Callable[[], None]]:
    out, size, m = args.out, args.size, args.minutes
    pre = m * args.pretrain
    pre_ckpt = out / "fits" / "a-pretrained"
    mix = "[{source: procedural, weight: 0.5}, {source: des18, weight: 0.5, validation: 0}]"

    def copy():
        pre_ckpt.mkdir(parents=True, exist_ok=True)
        for name in ("last.pt", "last.json"):
            shutil.copy2(fit_folder(out, "a", 0) / name, pre_ckpt / name)

    later = [
        Job(
            "a (resumed)",
            [sys.executable, "-m", "svbrdf_train", "fit", "--resume", "--out", str(fit_folder(out, "a", 0)),
             "--max-minutes", f"{m:g}", "-q"],
        )
    ]  # fmt: skip
    first = []
    for k, (train, judge) in enumerate(folds):
        real = ("--data", str(train), "--set", "data.validation=0")
        first.append(Job(f"b{k}", fit_args(RECIPES["b"], size, f"b-real-fold{k}", fit_folder(out, "b", k), m,
                                           judge, *real)))
        first.append(Job(f"c{k}", fit_args(RECIPES["c"], size, f"c-mix-fold{k}", fit_folder(out, "c", k), m,
                                           judge, "--data", str(train), "--set", "data.count=20000",
                                           "--set", f"data.mix={mix}")))
        later.append(Job(f"d{k}", fit_args(RECIPES["d"], size, f"d-finetune-fold{k}",
                                            fit_folder(out, "d", k), m - pre, judge, *real,
                                            "--init", str(pre_ckpt))))  # fmt: skip
    a = Job(
        "a (pre-training)",
        fit_args(RECIPES["a"], size, "a-procedural", fit_folder(out, "a", 0), pre, folds[0][1],
                 "--set", "data.count=20000"),
        then=later,
    )  # fmt: skip
    return [a, *first], copy


def run_jobs(jobs: list[Job], copy: Callable[[], None], parallel: int, env: dict, prog: str = "real_mix") -> None:
    """Run ``jobs``, ``parallel`` at a time, each logging to its ``--out`` folder's ``.log``;
    a job's ``then`` start when it ends (after ``copy()``). A failed job ends the program
    (exit 1, naming its log). ``benchmarks/generalisation.py`` runs its fits with it too."""
    queue = list(jobs)
    running: list[tuple[Job, subprocess.Popen, float, object]] = []
    while queue or running:
        while queue and len(running) < parallel:
            job = queue.pop(0)
            folder = Path(job.args[job.args.index("--out") + 1])
            folder.parent.mkdir(parents=True, exist_ok=True)
            log = open(folder.with_suffix(".log"), "a")  # noqa: SIM115 (closed when the job ends)
            print(f"[{time.strftime('%H:%M:%S')}] start {job.name}: {' '.join(job.args[1:])}", flush=True)
            proc = subprocess.Popen(job.args, env=env, stdout=log, stderr=log)
            running.append((job, proc, time.time(), log))
        time.sleep(2)
        for item in list(running):
            job, proc, start, log = item
            if proc.poll() is None:
                continue
            running.remove(item)
            log.close()
            took = (time.time() - start) / 60
            print(f"[{time.strftime('%H:%M:%S')}] {job.name} ended (exit {proc.returncode}, {took:.1f} min)")
            if proc.returncode != 0:
                sys.exit(f"{prog}: error: fit {job.name} failed; its log: {log.name}")
            if job.then:
                copy()
                queue = job.then + queue


def run_id(folder: Path) -> str:
    return json.loads((folder / "last.json").read_text())["run_id"]


# -- judging ------------------------------------------------------------------------------------


def per_image(parents: list[str]) -> dict[str, dict[str, list[float]]]:
    """Per-image RMSE of every variant and of ``mean``, both folds in a row, as the fold's
    benchmark (MLflow parent run) scored them."""
    from svbrdf_bench.report import build_report

    scores: dict[str, dict[str, list[float]]] = {}
    for parent in parents:
        entries = {e.label: e for e in build_report(parent).models}
        for name in (*VARIANTS, "mean"):
            per_sample = entries[RECIPES.get(name, name)].per_sample
            for c in COLUMNS:
                scores.setdefault(name, {}).setdefault(c, []).extend(per_sample[f"rmse/{c}"].tolist())
    return scores


def pooled_table(scores: dict[str, dict[str, list[float]]], n_images: int) -> str:
    from svbrdf_bench.metrics import bootstrap_ci, paired_difference

    head = "| model | " + " | ".join(COLUMNS) + " |\n| --- |" + " ---: |" * len(COLUMNS)
    rows = [head]
    for name in (*VARIANTS, "mean"):
        cells = []
        for c in COLUMNS:
            m, lo, hi = bootstrap_ci(scores[name][c])
            cells.append(f"{m:.4f} [{lo:.4f}, {hi:.4f}]")
        rows.append(f"| {LABELS.get(name, '`mean` (baseline)')} | " + " | ".join(cells) + " |")
    rows += ["", "Against `mean` (paired, % of `mean`'s RMSE; beats / worse: the interval excludes 0):", ""]
    rows += [head]
    for name in VARIANTS:
        cells = []
        for c in COLUMNS:
            base = sum(scores["mean"][c]) / len(scores["mean"][c])
            cells.append(paired_difference(scores[name][c], scores["mean"][c]).percent_of(base))
        rows.append(f"| {LABELS[name]} | " + " | ".join(cells) + " |")
    render = {v: sum(scores[v]["render"]) for v in VARIANTS}
    best = min(VARIANTS, key=render.get)
    rows += ["", f"{LABELS[best]}, the best on renderings, against the others (paired, % of theirs):", ""]
    rows += [head]
    for name in VARIANTS:
        if name == best:
            continue
        cells = []
        for c in COLUMNS:
            base = sum(scores[name][c]) / len(scores[name][c])
            cells.append(paired_difference(scores[best][c], scores[name][c]).percent_of(base, "better"))
        rows.append(f"| against {LABELS[name]} | " + " | ".join(cells) + " |")
    title = f"RMSE over the {n_images} strips of both judging folds (95% bootstrap intervals):"
    return title + "\n\n" + "\n".join(rows)


def judge(args, folds: list[tuple[Path, Path]], env: dict) -> int:
    parents = []
    for k, (_, judge_folder) in enumerate(folds):
        ids = [run_id(fit_folder(args.out, v, k)) for v in VARIANTS]
        bench = [
            sys.executable, "-m", "svbrdf_bench", "run", "--from-runs", ",".join(ids),
            "--test-data", str(judge_folder), "--experiment", "real-mix",
            "-o", str(args.out / f"report-fold{k}"),
        ]  # fmt: skip
        print(f"[{time.strftime('%H:%M:%S')}] judging fold {k}: {' '.join(bench[1:])}", flush=True)
        done = subprocess.run(bench, env=env)
        if done.returncode != 0:
            return done.returncode
        parents.append(json.loads((args.out / f"report-fold{k}" / "results.json").read_text())["parent_run"])
    scores = per_image(parents)
    n = len(scores["mean"]["render"])
    text = pooled_table(scores, n)
    (args.out / "pooled.md").write_text(text + "\n")
    print("\n" + text)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("data", type=Path, help="a Des18 folder of strips with ground truth (e.g. des18-dev)")
    p.add_argument("-o", "--out", type=Path, default=Path("real-mix"), help="folds, fits and reports")
    p.add_argument("--minutes", type=float, default=30.0, help="training budget per variant (default 30)")
    p.add_argument("--pretrain", type=float, default=2 / 3, help="share of (d)'s budget on procedural data")
    p.add_argument("--size", default="cpu", choices=("cpu", "smoke", "paper"))
    p.add_argument("--jobs", type=int, default=1, help="fits at a time (each gets --threads threads)")
    p.add_argument("--threads", type=int, default=None, help="torch threads per fit (default: torch's)")
    p.add_argument("--judge-only", action="store_true", help="judge the fits already in OUT/fits")
    p.add_argument("--print", dest="show", action="store_true", help="print the commands, run nothing")
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(f"real_mix: error: {args.data}: not a folder; give a Des18 folder of strips", file=sys.stderr)
        return 2
    if not 0 < args.pretrain < 1 or args.minutes <= 0 or args.jobs < 1:
        print("real_mix: error: --pretrain must be in (0, 1), --minutes and --jobs positive", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    folds = make_folds(args.data, args.out)
    for k, (train, judge_folder) in enumerate(folds):
        n_train, n_judge = len(strips(train)), len(strips(judge_folder))
        print(f"fold {k}: {n_train} strips train, {n_judge} judge ({judge_folder})")
    env = dict(os.environ)
    if args.threads:
        env["OMP_NUM_THREADS"] = str(args.threads)
    if not args.judge_only:
        jobs, copy = plan(args, folds)
        if args.show:
            for job in jobs:
                for j in (job, *job.then):
                    print(f"{j.name}: {' '.join(j.args[1:])}")
            return 0
        run_jobs(jobs, copy, args.jobs, env)
    return judge(args, folds, env)


if __name__ == "__main__":
    sys.exit(main())
