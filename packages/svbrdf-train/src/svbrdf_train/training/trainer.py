"""The GAN trainer: one fit of a recipe, tracked in MLflow, resumable, on one process or many.

A fit puts together the step (:class:`~svbrdf_train.training.step.GanStep`: G, D, optimisers,
schedule), the batch order (:class:`~svbrdf_train.training.order.BatchOrder`) and the hooks that log,
validate and write checkpoints between steps (:mod:`svbrdf_train.training.hooks`, each given a
read-only view of the run: :mod:`svbrdf_train.training.run`); :func:`fit` runs the loop. Learning
rates follow the paper's step decay counted in samples seen (:mod:`svbrdf_train.training.schedule`).
Training time is counted without validation and checkpoint writing, so ``max_minutes`` budgets
compare models fairly.

Stopping: at the step budget (``epochs``, ``max_steps``) or the time budget; on a non-finite
loss (FAILED: nothing is stepped with it and the last checkpoint stays as it was); on Ctrl-C
or SIGTERM (KILLED, after saving a checkpoint at the end of the current step).

Reproducibility: every random draw comes from the seed, the step and random states saved in
the checkpoint, so a fit stopped at any point and resumed reaches the same weights as one that
never stopped; bitwise on CPU with the same number of threads and processes.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import torch

from svbrdf_render.errors import OutputError, SVBRDFError
from svbrdf_render.plumbing import write_text

from ..errors import CheckpointError
from ..recipe import Recipe, check_recipe
from . import distributed
from .checkpoint import CHECKPOINT_NAME, check_resumable, check_run_kept
from .clock import Stopwatch, TrainClock
from .hooks import BudgetWarning, Checkpoints, HookRunner, KeepBest, Logging, Snapshots, Validation
from .order import BatchOrder
from .progress import Interrupt, Progress, format_duration
from .resume import check_out, check_world, resolve_resume
from .run import Run, StepEnd
from .step import GanStep
from .validation import Validator

__all__ = ["FitOptions", "FitResult", "fit"]


@dataclass
class FitOptions:
    """How to run a fit (the recipe says what to train).

    Attributes:
        out: folder of the checkpoint (``last.pt``), the resolved recipe and sample grids.
        resume: continue from ``out/last.pt`` (and its MLflow run).
        force: start afresh even though ``out`` holds a checkpoint (it is replaced).
        device: ``auto``, ``cpu``, ``cuda`` or ``cuda:K``.
        experiment: MLflow experiment name.
        run_name: MLflow run name (default ``<recipe>-<size>``).
        progress: show the progress line.
        track: log to MLflow (rank 0); False records nothing but the local files.
        parent_run: make the MLflow run a child of this run (a benchmark's parent run).
        init: start from these weights (a checkpoint file, a fit's folder or an MLflow run id;
            :mod:`svbrdf_train.training.init`) in a new fit and a new run.
        overrides: with ``resume`` and no recipe, dotted overrides of the checkpoint's recipe
            (``{"train.max_steps": 8}``; budgets and cadences: :data:`~.resume.RESUMABLE_CHANGES`).
    """

    out: Path
    resume: bool = False
    force: bool = False
    device: str = "auto"
    experiment: str = "svbrdf"
    run_name: str | None = None
    progress: bool = True
    track: bool = True
    parent_run: str | None = None
    init: str | None = None
    overrides: dict = field(default_factory=dict)


@dataclass
class FitResult:
    """How a fit ended. ``status`` is MLflow's: FINISHED, FAILED or KILLED."""

    status: str
    step: int
    total_steps: int
    run_id: str | None
    checkpoint: Path | None
    train_seconds: float
    message: str
    metrics: dict[str, float] = field(default_factory=dict)
    samples_per_s: float | None = None
    """Training throughput of all processes after the first :data:`~.clock.WARMUP_STEPS` steps of this
    session (None when it made no more steps than that)."""
    best: dict[str, Any] | None = None
    """With ``train.keep_best``: ``{"metric", "value", "step"}`` of the weights in ``OUT/best.pt``."""

    @property
    def exit_code(self) -> int:
        return {"FINISHED": 0, "KILLED": 130}.get(self.status, 1)


def fit(recipe: Recipe | None, options: FitOptions) -> FitResult:
    """Train ``recipe`` (None with ``options.resume``: the checkpoint's recipe); see the module doc.

    Raises:
        RecipeError, DataError, CheckpointError, TrainingError: before training starts, for
            settings that cannot work (each names what to change).
    """
    dist = distributed.init(options.device)
    try:
        return _fit(recipe, options, dist)
    finally:
        dist.close()


def _fit(recipe: Recipe | None, options: FitOptions, dist: distributed.Dist) -> FitResult:
    o = options
    state = check_out(Path(o.out), resume=o.resume, force=o.force, init=o.init, main=dist.main)
    if state is not None:
        ckpt = Path(o.out) / CHECKPOINT_NAME
        check_resumable(state, str(ckpt))
        if o.track and dist.main and state.get("run_id"):
            run_id = state["run_id"]
            check_run_kept(
                run_id,
                f"{ckpt} continues a deleted run",
                f"restore it (mlflow runs restore --run-id {run_id}), resume without MLflow "
                "(--no-track), or start a new fit and run (--force, without --resume)",
            )
    recipe = resolve_resume(recipe, state, Path(o.out) / CHECKPOINT_NAME, o.overrides)
    if not recipe.checked:  # made in Python: load_recipe's and a resumed one are checked already
        check_recipe(recipe, recipe.source or recipe.name)
    run, real_name = _setup(recipe, options, dist, state)
    del state  # a paper-size checkpoint: over 1 GB
    if dist.main:
        _start_tracking(run, options, real_name)
    view = run.view()  # the hooks see the run through read-only views; the runner applies their changes
    validation = Validation(view)
    keep = KeepBest(view, validation)
    hooks = HookRunner([BudgetWarning(view), Logging(view), validation, keep, Snapshots(view), Checkpoints(view)])
    status, message = _loop(run, hooks)
    run.progress.close()
    if status == "FINISHED" and not message:
        message = f"{run.gan.step} steps, {format_duration(run.watch.seconds)} of training"
    if dist.main:
        from .fitlog import summary_metrics

        run.tracker.set_tags({"svbrdf.stop": message, "svbrdf.steps": run.gan.step})
        run.tracker.log_metrics(summary_metrics(run), run.gan.step)
        if status == "FINISHED":  # the generator as an MLflow model of the run (pyfunc)
            from .export import log_fit_model

            log_fit_model(run, validation.metrics)
    run.tracker.finish(status)
    return FitResult(
        status=status,
        step=run.gan.step,
        total_steps=run.order.total_steps,
        run_id=run.run_id,
        checkpoint=run.ckpt_path if run.ckpt_path.is_file() else None,
        train_seconds=run.watch.seconds,
        message=message,
        metrics=validation.metrics,
        samples_per_s=run.watch.steady_rate(),
        best=keep.best,
    )


def _setup(
    recipe: Recipe, options: FitOptions, dist: distributed.Dist, state: dict | None
) -> tuple[Run, str | None]:
    """The run of a fit: data, the step (weights from ``--init`` or the checkpoint), hooks' state."""
    from ..data.fitdata import fold_validation_set, real_validation_set
    from ..tracking import made_with

    t, out = recipe.train, Path(options.out)
    train_set, val_set = recipe.data.setup(t.resolution)
    real = real_validation_set(recipe.data.real_validation, t.resolution)
    fold = fold_validation_set(recipe.data, t.resolution)
    order = BatchOrder(train_set, recipe, dist.rank, dist.world, dist.device)
    gan = GanStep(recipe, dist, order.epoch_samples)
    watch = Stopwatch(TrainClock(t.clock, dist.device))
    run_id, init = None, None
    if state is not None:
        ckpt = out / CHECKPOINT_NAME
        check_world(state, dist.world, ckpt)
        if state["step"] > order.total_steps:
            raise CheckpointError(
                f"{ckpt}: its step {state['step']} is beyond the budget of {order.total_steps} steps "
                f"(train.epochs={t.epochs} of {order.steps_per_epoch} steps, train.max_steps="
                f"{t.max_steps if t.max_steps is not None else 'null'}); raise --max-steps or "
                "train.epochs (--set train.epochs=N) to go on from it"
            )
        try:
            gan.load_state_dict(state, str(ckpt))
            gan.set_rng_state(state["rng"][dist.rank])
        except (KeyError, TypeError, ValueError, RuntimeError) as e:  # torch's own checks
            first = str(e).splitlines()[0][:200] if str(e) else type(e).__name__
            raise CheckpointError(
                f"{ckpt}: its optimiser or random state cannot be restored ({first}); "
                "the checkpoint is damaged: start a new fit (--force) or use another --out"
            ) from None
        watch.seconds = float(state.get("train_seconds", 0.0))
        watch.wall_seconds = float(state.get("wall_seconds", watch.seconds))
        run_id, init = state.get("run_id"), state.get("init")
    else:
        from .init import take_init

        init = take_init(gan, options.init, recipe) if options.init else None
        torch.manual_seed(t.seed * 1000 + 1 + dist.rank)  # dropout differs per process
    gan.prepare()
    budget = t.max_minutes * 60 if t.max_minutes is not None else None
    progress = Progress(
        order.total_steps, start=gan.step, budget_s=budget, enabled=options.progress, messages=dist.main
    )
    validator = Validator(val_set, real[0] if real else None, t.batch, dist.device, fold[0] if fold else None)
    run = Run(
        recipe, dist, gan, order, validator, out, watch, progress,
        run_id=run_id, init=init, start_step=gan.step, saved_at=gan.step, made_with=made_with(dist.device),
    )  # fmt: skip
    return run, real[1] if real else None


def _start_tracking(run: Run, options: FitOptions, real_name: str | None) -> None:
    """The folder, the resolved recipe in it, the MLflow run, and the plan on the terminal."""
    import yaml

    from .fitlog import open_tracker, plan

    run.out.mkdir(parents=True, exist_ok=True)
    config_file = write_text(run.out / "recipe.yaml", yaml.safe_dump(run.recipe.to_dict(), sort_keys=False))
    if options.track:
        run.tracker = open_tracker(run, options.experiment, options.run_name, options.parent_run)
        run.run_id = run.tracker.run_id
        if run.start_step == 0:
            from ..tracking import log_fit_inputs

            run.tracker.log_artifact(config_file, "config")
            log_fit_inputs(run.tracker, run.recipe, parent_run=options.parent_run)
    run.progress.message(plan(run, real_name))


def _loop(run: Run, hooks: HookRunner) -> tuple[str, str]:
    """Steps until a budget, a stop request or a non-finite value: ``(status, message)``."""
    with Interrupt(run.progress) as interrupt:
        try:
            return _steps(run, hooks, interrupt)
        except KeyboardInterrupt:
            kept = f"the checkpoint of step {run.saved_at} is kept"
            return "KILLED", f"stopped at once at step {run.gan.step}; {kept}"
        except BaseException as e:
            run.progress.close()
            with contextlib.suppress(Exception):  # the store may be what failed: keep that error
                run.tracker.finish("FAILED")
            if isinstance(e, SVBRDFError) and e.exit_code == OutputError.exit_code:
                from .fitlog import with_checkpoint_kept

                raise with_checkpoint_kept(e, run) from None
            raise


def _steps(run: Run, hooks: HookRunner, interrupt: Interrupt) -> tuple[str, str]:
    t, gan, dist = run.recipe.train, run.gan, run.dist
    run.watch.start()
    for batch in run.order.batches(gan.step):
        terms, bad = gan(batch)
        samples = batch["input"].shape[0] * dist.world
        run.watch.lap(samples)
        if bad is not None:
            from .fitlog import nan_message

            return "FAILED", nan_message(run, bad)
        time_up = t.max_minutes is not None and run.watch.seconds >= t.max_minutes * 60
        stop, time_up, *passed = dist.any(interrupt.requested is not None, time_up, *hooks.minutes_passed())
        last = gan.step >= run.order.total_steps or stop or time_up
        hooks.after_step(run, StepEnd(gan.step, terms, samples, last=last), passed)
        if stop:
            return "KILLED", f"stopped by {interrupt.requested or 'another process'} at step {gan.step}"
        if time_up:
            return "FINISHED", f"time budget of {t.max_minutes:g} min reached at step {gan.step}"
        run.watch.start()
    return "FINISHED", ""
