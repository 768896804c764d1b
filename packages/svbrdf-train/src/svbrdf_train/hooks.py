"""What a fit does between its steps, as hooks the training loop calls after each step.

=================  ==========================================================================
hook               after a step
=================  ==========================================================================
BudgetWarning      once the pace is known, warns if the schedule stops learning early, and
                   if the step budget ends the fit long before its time budget
Logging            the progress line; ``train/...`` metrics every ``train.log_every`` steps
Validation         ``val/...`` metrics and a sample grid every ``train.validate_every`` steps
Checkpoints        the full state to ``OUT/last.pt`` every ``train.checkpoint_every`` steps or
                   ``train.checkpoint_minutes``; the weights to MLflow every
                   ``train.upload_minutes``
=================  ==========================================================================

Every hook also runs after the last step (``StepEnd.last``: the step budget, the time budget
or a stop request). A hook is any object with ``after_step(run, end)``; the loop calls them in
order, on every process (a hook that logs acts on the main process only).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from . import distributed
from .checkpoint import CHECKPOINT_NAME, WEIGHTS_NAME, save_checkpoint
from .clock import Stopwatch
from .order import BatchOrder
from .progress import Progress, format_duration
from .recipe import Recipe
from .step import GanStep
from .tracking import Tracker
from .validation import Validator

__all__ = ["Run", "StepEnd", "Hook", "BudgetWarning", "Logging", "Validation", "Checkpoints"]
#: Checkpoint fields a user of the weights needs (predict, --init); the rest is for resuming.
WEIGHT_FIELDS = (
    "recipe", "step", "epoch", "generator", "discriminator", "run_id", "init",
    "train_seconds", "wall_seconds", "world_size", "made_with",
)  # fmt: skip


@dataclass
class Run:
    """Everything one fit has: what it trains, with what, where it writes, how it reports."""

    recipe: Recipe
    dist: distributed.Dist
    gan: GanStep
    order: BatchOrder
    validator: Validator
    out: Path
    watch: Stopwatch
    progress: Progress
    tracker: Tracker = field(default_factory=Tracker)
    run_id: str | None = None
    init: dict[str, str] | None = None  # where the starting weights came from (MLflow tags)
    start_step: int = 0
    saved_at: int = 0  # the step of the last checkpoint written
    made_with: dict[str, str] = field(default_factory=dict)  # code revision and machine (tracking.made_with)

    @property
    def ckpt_path(self) -> Path:
        return self.out / CHECKPOINT_NAME

    def state(self, rngs: list) -> dict[str, Any]:
        """The checkpoint: the step's state, every process's random state, the run's bookkeeping."""
        return {
            "recipe": self.recipe.to_dict(),
            **self.gan.state_dict(),
            "epoch": self.gan.step // self.order.steps_per_epoch,
            "rng": rngs,
            "run_id": self.run_id,
            "init": self.init,
            "train_seconds": self.watch.seconds,
            "wall_seconds": self.watch.wall_seconds,
            "world_size": self.dist.world,
            "made_with": self.made_with,
        }


@dataclass
class StepEnd:
    """One step as the hooks see it; the flags are the same on every process."""

    step: int
    terms: dict[str, float]
    samples: int  # of all processes
    last: bool  # the fit stops after this step
    checkpoint_due: bool = False  # train.checkpoint_minutes have passed since the last one


class Hook(Protocol):
    def after_step(self, run: Run, end: StepEnd) -> None: ...


class BudgetWarning:
    """Says once, on the main process and in the run's tags, that the learning-rate schedule
    kills the rate early in the budget: at once for a step budget; for a time budget once
    the pace is known (:meth:`Stopwatch.pace`).

    With a time budget (``train.max_minutes``) it also says, after the first step, when the
    step budget (``train.epochs``, ``train.max_steps``) will end the fit in less than half that
    time (17 strips at batch 4 and 2 epochs are 8 steps: seconds, not the minutes asked for).
    The first step is the slowest (lazy initialisation, compilation), so its time makes the
    estimate long, never short: a warning is due; without one, the pace is looked at again
    once it is known.
    """

    def __init__(self, run: Run):
        self.done = run.recipe.train.max_minutes is None  # a step budget is known now
        self.time_checked = self.done
        if self.done:
            self._warn(run, run.order.total_steps, "the step budget")

    def after_step(self, run: Run, end: StepEnd) -> None:
        if not self.time_checked:
            self._time_budget(run, end)
        pace = run.watch.pace()
        if self.done or pace is None or pace <= 0:
            return
        minutes = run.recipe.train.max_minutes
        steps = min(run.order.total_steps, end.step + int((minutes * 60 - run.watch.seconds) / pace))
        self._warn(run, steps, f"{minutes:g} min at {pace * 1000:.0f} ms/step")
        self.done = True

    def _time_budget(self, run: Run, end: StepEnd) -> None:
        """Warn when the step budget ends the fit in under half of ``train.max_minutes``."""
        t, watch = run.recipe.train, run.watch
        pace = watch.pace()
        per_step = pace if pace is not None else watch.seconds / max(1, end.step)
        self.time_checked = pace is not None or end.last
        left = run.order.total_steps - end.step
        if end.last or per_step <= 0 or watch.seconds + left * per_step >= 0.5 * t.max_minutes * 60:
            return
        self.time_checked = True
        if run.order.total_steps == t.max_steps:
            steps, fix = f"train.max_steps={t.max_steps}", "raise --max-steps (or leave it out)"
        else:
            steps = f"train.epochs={t.epochs} of {run.order.steps_per_epoch} steps"
            fix = "raise train.epochs (--set train.epochs=N)"
        text = (
            f"warning: the time budget (train.max_minutes={t.max_minutes:g}) will not be reached: the "
            f"step budget of {run.order.total_steps} steps ({steps}) ends the fit after about "
            f"{format_duration(watch.seconds + left * per_step)} of training; {fix} to train for "
            "the whole time"
        )
        if run.dist.main:
            run.progress.message(text)
            run.tracker.set_tags({"svbrdf.warning.time_budget": text[:5000]})

    @staticmethod
    def _warn(run: Run, steps: int, what: str) -> bool:
        text = run.gan.schedule.warning(steps, what)
        if text is None:
            return False
        if run.dist.main:
            run.progress.message(text)
            run.tracker.set_tags({"svbrdf.warning": text[:5000]})
        return True


class Logging:
    """The progress line after every step; the mean loss terms, rate and schedule every
    ``train.log_every`` steps and after the last (``train/...``)."""

    SHOWN = ("loss", "adv", "render", "svbrdf", "d_loss")

    def __init__(self, run: Run):
        self.sums: dict[str, float] = {}
        self.count = 0
        self.window = (run.watch.seconds, 0)  # (training seconds, samples) since the last log

    def after_step(self, run: Run, end: StepEnd) -> None:
        for k, v in end.terms.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.count += 1
        seconds = run.watch.seconds
        self.window = (self.window[0], self.window[1] + end.samples)
        rate = self.window[1] / max(seconds - self.window[0], 1e-9)
        run.progress.update(end.step, {k: end.terms[k] for k in self.SHOWN if k in end.terms}, rate, seconds)
        if end.step % run.recipe.train.log_every and end.step != run.order.total_steps:
            return
        metrics = {f"train/{k}": v / self.count for k, v in self.sums.items()}
        metrics.update(
            {
                "train/lr": run.gan.g_opt.param_groups[0]["lr"],
                "train/samples_per_s": rate,
                "train/epoch": end.step / run.order.steps_per_epoch,
                "train/seconds": seconds,
            }
        )
        run.tracker.log_metrics(metrics, end.step)
        self.sums, self.count, self.window = {}, 0, (seconds, 0)


class Validation:
    """``val/`` (and ``val_real/``) metrics, with the training time so far so that curves can be
    drawn against time, and the sample grid as ``samples/step_N.png`` (main process)."""

    def __init__(self):
        self.metrics: dict[str, float] = {}  # the last validation's

    def after_step(self, run: Run, end: StepEnd) -> None:
        if not run.dist.main or not (end.last or end.step % run.recipe.train.validate_every == 0):
            return
        metrics, grid = run.validator(run.gan.generator)
        if metrics:
            run.tracker.log_metrics({**metrics, "val/train_seconds": run.watch.seconds}, end.step)
        if grid is not None:
            from svbrdf_render import write_image

            path = write_image(run.out / "samples" / f"step_{end.step:07d}.png", grid)
            run.tracker.log_artifact(path, "samples")
            run.tracker.log_image(path, "samples", end.step)  # the same grid, with a step slider
        self.metrics = metrics


class Checkpoints:
    """The full state to ``OUT/last.pt`` (every process's random state gathered to the main
    one), and the weights alone to ``OUT/weights.pt`` and the MLflow run, less often.

    A checkpoint is written every ``train.checkpoint_every`` steps, when
    ``train.checkpoint_minutes`` of wall time have passed since the last one, and after the last
    step. The weights go to MLflow (``checkpoints/weights.pt``) after the last step and when
    ``train.upload_minutes`` have passed since the last upload: a paper-size checkpoint with
    both Adam states is about three times the weights, and MLflow keeps every upload's bytes
    until the run is deleted.
    """

    def __init__(self, run: Run):
        self.saved = self.uploaded = time.monotonic()

    def time_due(self, run: Run) -> bool:
        """Whether ``train.checkpoint_minutes`` have passed (ask every process: :class:`StepEnd`)."""
        minutes = run.recipe.train.checkpoint_minutes
        return minutes is not None and time.monotonic() - self.saved >= minutes * 60

    def after_step(self, run: Run, end: StepEnd) -> None:
        every = run.recipe.train.checkpoint_every
        if not (end.last or end.checkpoint_due or (every is not None and end.step % every == 0)):
            return
        rngs = run.dist.gather(run.gan.rng_state())
        if run.dist.main:
            state = run.state(rngs)
            save_checkpoint(run.ckpt_path, state)
            minutes = run.recipe.train.upload_minutes
            if end.last or (minutes is not None and time.monotonic() - self.uploaded >= minutes * 60):
                self._upload(run, state)
        run.dist.barrier()
        run.saved_at = end.step
        self.saved = time.monotonic()

    def _upload(self, run: Run, state: dict[str, Any]) -> None:
        weights = save_checkpoint(run.out / WEIGHTS_NAME, {k: state[k] for k in WEIGHT_FIELDS})
        run.tracker.log_artifact(weights, "checkpoints")
        self.uploaded = time.monotonic()
