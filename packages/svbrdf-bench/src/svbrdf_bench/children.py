"""The benchmark's runs in MLflow, one child run of the parent per row: a fit trained here (in its
own process, as a user would: :func:`train`; its checkpoint: :func:`fit_checkpoint`), a reused
fit (:func:`resolve_reuse`, :func:`reused_child`), a baseline (:func:`baseline_child`) and the
refined rows of any of them (:func:`log_refined_children`); each evaluated child gets its
figures and per-sample values (:func:`log_child`), laid out as :mod:`svbrdf_bench.layout`
describes. With seeds and budgets (:mod:`svbrdf_bench.seeding`) a fit is scored as one row or,
with several budgets, a row per budget from its snapshots (:func:`fit_rows`); a budget the fit
never reached is returned as missed, with why, never dropped without a word.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import BenchError
from .layout import (
    BUDGET_TAG,
    METHOD_TAG,
    MODEL_TAG,
    PARENT_TAG,
    PER_SAMPLE,
    REFERENCE_TAG,
    REFINE_TAG,
    REFINED_FROM_TAG,
    SEED_TAG,
    SNAPSHOT_TAG,
    STEPS_METRIC,
    STEPS_WALL_METRIC,
    TRAIN_RUN_TAG,
    baseline_tags,
    per_sample_json,
)
from .options import BenchOptions
from .refinement import RefinedRow, RefinePlan, refined_label
from .scoring import test_means
from .seeding import TrainBudget, row_label

__all__ = [
    "tracking_client",
    "resolve_reuse",
    "fits_folder",
    "train",
    "fit_checkpoint",
    "log_child",
    "log_refined_children",
    "baseline_child",
    "reused_child",
    "fit_seed",
    "Fit",
    "FitRow",
    "fit_rows",
    "snapshot_checkpoint",
    "snapshot_figures",
]


def tracking_client():
    """The client of the tracking store, which is created (quietly, one process at a time) if new."""
    import mlflow

    from svbrdf_train import open_client

    return open_client(mlflow.get_tracking_uri())


def resolve_reuse(
    items: Sequence[str], seeds: int = 1, trainable: Sequence[str] = ()
) -> list[tuple[str, str]]:
    """``--from-runs`` items (run ids or recipe names) -> ``(model label, run id)``.

    Several fits of one recipe with different seeds (``train.seed``) keep the recipe's label:
    they are seeds of one model; two of one seed are told apart by their run's name. A recipe name
    is its last finished fit, or with ``seeds`` > 1 the last finished fit of each seed s in
    0..seeds-1 (``train.seed`` = ``data.seed`` = s); seeds without one are refused unless the
    recipe is in ``trainable`` (``--models``: the benchmark trains them)."""
    client = tracking_client()
    out: list[tuple[str, str]] = []
    seen: set[tuple[str, int]] = set()
    for item in items:
        try:
            run = client.get_run(item)
        except Exception:  # not a run id: a recipe name
            run = None
        if run is not None and TRAIN_RUN_TAG in run.data.tags:  # a benchmark's child of a reused fit
            run = client.get_run(run.data.tags[TRAIN_RUN_TAG])
        runs = [run] if run is not None else _finished_fits(client, item, seeds, item in trainable)
        for fit in runs:
            label = (fit.data.tags.get("recipe") or item) if run is not None else item
            if (label, fit_seed(fit)) in seen:  # two fits of one recipe and seed: tell them apart
                label = fit.info.run_name or f"{label}-{fit.info.run_id[:8]}"
            seen.add((label, fit_seed(fit)))
            out.append((label, fit.info.run_id))
    return out


def fit_seed(run) -> int:
    """The seed of a fit's MLflow run: its ``train.seed`` (0 when not recorded)."""
    try:
        return int(float(run.data.params.get("train.seed", 0)))
    except ValueError:
        return 0


def _finished_fits(client, recipe: str, seeds: int, trainable: bool) -> list:
    """The last finished fit of ``recipe``, or with ``seeds`` > 1 of each seed that has one."""
    experiments = [e.experiment_id for e in client.search_experiments()]
    where = f"tags.recipe = '{recipe}' and attributes.status = 'FINISHED'"
    wheres = [where] if seeds == 1 else [
        f"{where} and params.`train.seed` = '{s}' and params.`data.seed` = '{s}'" for s in range(seeds)
    ]  # fmt: skip
    found = []
    for w in wheres:
        runs = [
            r  # the fits themselves, not the benchmark children that only point at one
            for r in client.search_runs(experiments, filter_string=w, order_by=["attributes.end_time DESC"],
                                        max_results=50)  # fmt: skip
            if TRAIN_RUN_TAG not in r.data.tags
        ]
        found += runs[:1]
    if not found and (seeds == 1 or not trainable):
        raise BenchError(
            f"--from-runs {recipe}: neither a run id nor the recipe of a finished run "
            f"in {client.tracking_uri}"
        )
    if seeds > 1 and len(found) < seeds and not trainable:
        have = ", ".join(str(fit_seed(r)) for r in found)
        raise BenchError(
            f"--from-runs {recipe}: finished fits of seeds {have} only, of the {seeds} --seeds asks for; "
            f"add {recipe} to --models to train the others, or give --seeds {len(found)}"
        )
    return found


def fits_folder(out: Path) -> Path:
    """Where a benchmark with report folder ``out`` trains its fits: ``OUT-fits`` beside it, kept
    when the benchmark stops before its end (the same command then resumes each unfinished fit:
    :func:`train`) and removed when it finishes."""
    out = Path(out)
    return out.with_name(f"{out.name}-fits")


def train(
    model: str, options: BenchOptions, parent: str, work: Path, *, seed: int | None = None,
    budget: TrainBudget | None = None, name: str | None = None,
) -> tuple[str, float, Path]:  # fmt: skip
    """Train one recipe in its own process (as a user would): its run id, wall seconds and folder.
    ``seed``: ``train.seed`` and ``data.seed`` (None: the recipe's); ``budget``: how long, with
    snapshots at its marks (default: the options'); ``name``: the run's (default: the recipe's).

    A fit the same arguments started before in ``work`` (a benchmark stopped in the middle, run
    again) is resumed from its checkpoint, in its MLflow run, now a child of ``parent``; its
    arguments are recorded beside its folder (``NAME.json``), so another fit is never resumed."""
    p = options.preset
    budget = budget or options.train_budget()
    name = name or Path(model).stem
    out = work / name.replace(" ", "-")
    size = options.size or p.size
    args = [
        "--recipe", model, "--size", size, "--experiment", options.experiment, "--run-name", name,
        "--set", f"train.validate_every={p.validate_every}", "--device", options.device,
        *budget.fit_args(),
    ]  # fmt: skip
    if seed is not None:
        args += ["--set", f"train.seed={seed}", "--set", f"data.seed={seed}"]
    for item in (*p.overrides, *options.overrides):
        args += ["--set", item]
    record = out.with_name(out.name + ".json")
    fit = [sys.executable, "-m", "svbrdf_train", "fit", "--out", str(out), "--parent-run", parent]
    if (out / "last.json").is_file() and record.is_file() and json.loads(record.read_text()) == args:
        options.say(f"  resuming {name} from its checkpoint in {out} (a run of this benchmark stopped there)")
        cmd = [*fit, "--resume"]
    else:
        work.mkdir(parents=True, exist_ok=True)
        record.write_text(json.dumps(args))
        cmd = [*fit, "--force", *args]
    start = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise BenchError(f"training {name} failed (exit {done.returncode}); its messages are above")
    summary = json.loads((out / "last.json").read_text())
    return summary["run_id"], wall, out


def fit_checkpoint(run_id: str, local: Path | None) -> dict:
    """The fit's checkpoint: the file it wrote here, else the weights logged in its run (or an
    older run's whole checkpoint)."""
    from svbrdf_train import load_checkpoint

    if local is None:
        from svbrdf_train import download_run_checkpoint

        return download_run_checkpoint(run_id)
    return load_checkpoint(local, source=f"the checkpoint of MLflow run {run_id}")


# -- evaluation ---------------------------------------------------------------------------------


def log_child(run_id: str, figures: dict[str, float], per_sample: dict[str, np.ndarray], work: Path) -> None:
    from mlflow.entities import Metric

    client = tracking_client()
    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(k, float(v), now, 0) for k, v in figures.items()])
    target = work / f"eval-{run_id}" / Path(PER_SAMPLE).name
    target.parent.mkdir(exist_ok=True)
    target.write_text(per_sample_json(per_sample))
    client.log_artifact(run_id, str(target), str(Path(PER_SAMPLE).parent))


def log_refined_children(
    client, experiment_id: str, parent_id: str, base: tuple[str, str, dict[str, str]],
    rows: dict[int, RefinedRow], plan: RefinePlan, params: float, work: Path,
) -> None:  # fmt: skip
    """A child run per refined budget of the row ``base`` = ``(label, child run id, extra tags)``;
    the extra tags (svbrdf.baseline, svbrdf.reference: a reference's short name) are the row's."""
    from mlflow.entities import Param

    label, base_run, extra = base
    name = extra.get(REFERENCE_TAG)
    for k, row in sorted(rows.items()):
        tags = {PARENT_TAG: parent_id, MODEL_TAG: refined_label(label, k, name), REFINE_TAG: str(k),
                REFINED_FROM_TAG: base_run, **extra}  # fmt: skip
        run_name = refined_label(name, k) + " (reference)" if name else refined_label(label, k)
        child = client.create_run(experiment_id, run_name=run_name, tags=tags).info.run_id
        client.log_batch(child, params=[Param(a, b) for a, b in plan.params(k).items()])
        figures = row.figures | test_means(row.per_sample) | {"model/params": params}
        log_child(child, figures, row.per_sample, work)
        client.set_terminated(child)


def baseline_child(client, experiment_id: str, parent_id: str, name: str) -> tuple[str, object]:
    """A child run for baseline ``name`` and its generator (built from the registry, untrained)."""
    from mlflow.entities import Param

    import svbrdf_models as sm

    config = sm.resolve_config("generator", name)
    child = client.create_run(
        experiment_id,
        run_name=f"{name} (baseline)",
        tags=baseline_tags(parent_id, name),
    )
    params = [Param(f"model.{k}", str(v)) for k, v in sm.config_to_dict(config).items()]
    client.log_batch(child.info.run_id, params=[Param("model.name", name), *params])
    return child.info.run_id, sm.create_generator(name).eval()


def reused_child(
    client, experiment_id: str, parent_id: str, label: str, source: str, *, run_name: str | None = None,
    tags: dict[str, str] | None = None,
) -> str:  # fmt: skip
    """The child run of a reused fit ``source`` (or of one budget of a fit: ``run_name``, its
    seed and budget ``tags``): tagged with it, and carrying its params (the whole recipe, the
    networks' configs, parameter counts), as the child of a fit trained here does, being that
    fit's own run. Returns the child's run id."""
    from mlflow.entities import Param

    fitted = client.get_run(source)
    child = client.create_run(
        experiment_id,
        run_name=run_name or f"{label} (reused)",
        tags={
            PARENT_TAG: parent_id,
            TRAIN_RUN_TAG: source,
            "recipe": fitted.data.tags.get("recipe", label),
            **(tags or {}),
        },
    )
    params = [Param(k, v) for k, v in sorted(fitted.data.params.items())]
    for start in range(0, len(params), 100):  # MLflow takes at most 100 params per batch
        client.log_batch(child.info.run_id, params=params[start : start + 100])
    return child.info.run_id


# -- the rows of one fit ------------------------------------------------------------------------


@dataclass(frozen=True)
class Fit:
    """One fit of a model: trained here (``out``: its folder) or reused (``out`` None)."""

    method: str
    seed: int
    run_id: str
    wall: float | None = None
    out: Path | None = None
    #: The model has several seeds here: each row's label says which.
    seeds_shown: bool = False


@dataclass
class FitRow:
    """One row to score from a fit: its label and child run (the fit's own run when it is scored
    whole, trained here), the fit's run, where its weights are, and its tags."""

    label: str
    run_id: str
    fit_run: str
    wall: float | None
    #: The weights here (a checkpoint or a snapshot); None: the fit's run's, in MLflow.
    local: Path | None
    #: Scored from this snapshot of the fit (``minutes-8.pt``); None: the fit's last weights.
    snapshot: str | None = None
    tags: dict[str, str] = field(default_factory=dict)


def fit_rows(client, parent, fit: Fit, budget: TrainBudget) -> tuple[list[FitRow], list[dict]]:
    """The rows of ``fit`` and the budgets it missed (``{model, seed, budget, why}``): one row
    for the whole fit (the fit's own run, or a child of a reused fit), or with several budgets a
    child run per budget it has a snapshot of."""
    seed = fit.seed if fit.seeds_shown else None
    tags = {SEED_TAG: str(fit.seed), METHOD_TAG: fit.method}
    if not budget.curve:
        words = budget.words() if fit.out is not None else None  # a reused fit: its own budget
        label = row_label(fit.method, seed, None)
        tags |= {BUDGET_TAG: words} if words else {}
        if fit.out is not None:
            return [FitRow(label, fit.run_id, fit.run_id, fit.wall, fit.out / "last.pt", tags=tags)], []
        child = reused_child(client, parent.experiment_id, parent.run_id, label, fit.run_id, tags=tags)
        return [FitRow(label, child, fit.run_id, None, None, tags=tags)], []
    if fit.out is not None:
        client.set_tag(fit.run_id, SEED_TAG, str(fit.seed))  # the fit's run: a child with no row
        client.set_tag(fit.run_id, METHOD_TAG, fit.method)
    taken = _snapshots_taken(client, fit)
    rows, missed = [], []
    for mark in budget.marks:
        words, name = budget.words(mark), budget.snapshot(mark)
        if name not in taken:
            missed.append({"model": fit.method, "seed": fit.seed, "budget": words, "why": _why(client, fit)})
            continue
        label = row_label(fit.method, seed, words)
        row_tags = tags | {BUDGET_TAG: words, SNAPSHOT_TAG: name}
        child = reused_child(client, parent.experiment_id, parent.run_id, label, fit.run_id,
                             run_name=label, tags=row_tags)  # fmt: skip
        local = fit.out / _snapshots_dir() / name if fit.out is not None else None
        rows.append(FitRow(label, child, fit.run_id, fit.wall, local, snapshot=name, tags=row_tags))
    return rows, missed


def _snapshots_dir() -> str:
    from svbrdf_train import SNAPSHOTS_DIR

    return SNAPSHOTS_DIR


def _snapshots_taken(client, fit: Fit) -> set[str]:
    """The snapshot files the fit saved: in its folder, else among its run's artifacts."""
    if fit.out is not None:
        return {p.name for p in (fit.out / _snapshots_dir()).glob("*.pt")}
    return {Path(a.path).name for a in client.list_artifacts(fit.run_id, _snapshots_dir())}


def _why(client, fit: Fit) -> str:
    """Why a fit has no snapshot at a budget: where it ended."""
    if fit.out is not None and (fit.out / "last.json").is_file():
        summary = json.loads((fit.out / "last.json").read_text())
        seconds = float(summary.get("train_seconds") or 0.0)
        step = summary.get("step")
        return f"the fit ended before it, at step {step} after {seconds / 60:.2f} min of training"
    seconds = client.get_run(fit.run_id).data.metrics.get("train/total_seconds")
    ended = f" (it ended after {seconds / 60:.2f} min of training)" if seconds is not None else ""
    return f"the reused fit saved no snapshot at it{ended}"


def snapshot_checkpoint(row: FitRow, work: Path) -> dict:
    """The weights of a row scored from a snapshot: its file here, else the fit's run's."""
    from svbrdf_train import load_checkpoint

    local = row.local
    if local is None:
        folder = work / f"snapshot-{row.run_id}"
        folder.mkdir(exist_ok=True)
        try:
            path = f"{_snapshots_dir()}/{row.snapshot}"
            local = Path(tracking_client().download_artifacts(row.fit_run, path, str(folder)))
        except Exception as e:  # MlflowException, OSError
            raise BenchError(f"MLflow run {row.fit_run}: cannot download its snapshot {row.snapshot} "
                             f"({type(e).__name__})") from None  # fmt: skip
    return load_checkpoint(local, source=f"the snapshot {row.snapshot} of MLflow run {row.fit_run}")


def snapshot_figures(figures: dict[str, float], record: dict) -> dict[str, float]:
    """A fit's training figures as of one of its snapshots (``record``: kind, mark, step, seconds):
    its training time and steps then; the fit's whole wall time is no figure of the snapshot."""
    out = {k: v for k, v in figures.items() if k not in ("time/train_wall_s", STEPS_WALL_METRIC)}
    return out | {"time/train_s": float(record["seconds"]), STEPS_METRIC: float(record["step"])}
