"""What a fit does between its steps, as hooks that declare when they run, and their runner.

=================  =====================================  ======================================
hook               runs (:class:`Cadence`)                does
=================  =====================================  ======================================
BudgetWarning      after every step                       once the pace is known, warns if the
                                                          schedule stops learning early, and if
                                                          the step budget ends the fit long
                                                          before its time budget
Logging            every ``train.log_every`` steps        ``train/...`` metrics: the window's
                   (the progress line after every step)   mean loss terms, rate and schedule
Validation         every ``train.validate_every`` steps,  ``val/...`` metrics and a sample grid
                   main process only
Checkpoints        every ``train.checkpoint_every``       the full state to ``OUT/last.pt``; the
                   steps and ``train.checkpoint_minutes`` weights to MLflow every
                                                          ``train.upload_minutes``
=================  =====================================  ======================================

Every hook also runs after the last step (``StepEnd.last``: the step budget, the time budget
or a stop request), so a fit that ends early still logs its last window. A hook is any object
with a ``cadence`` and ``after_step(run, end)`` (and, if it must see every step, ``observe(run,
end)``); :class:`HookRunner` is the one place that decides, after each step, which hooks run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ..recipe import Recipe
from ..tracking import Tracker
from . import distributed
from .checkpoint import CHECKPOINT_NAME, WEIGHTS_NAME, save_checkpoint
from .clock import Stopwatch
from .order import BatchOrder
from .progress import Progress, format_duration
from .step import GanStep
from .validation import Validator

__all__ = [
    "Run", "StepEnd", "Cadence", "Timer", "Hook", "HookRunner",
    "BudgetWarning", "Logging", "Validation", "Checkpoints",
]  # fmt: skip
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


@dataclass(frozen=True)
class Cadence:
    """When (and where) a hook runs: after every ``steps``-th step, after a step that ends at
    least ``minutes`` of wall time after the hook last ran (or the fit started), and after the
    last step (``at_end``); None leaves that measure out. ``main_only``: on the main process
    only (a hook that acts on every process, such as a checkpoint's gathering, leaves it off)."""

    steps: int | None = None
    minutes: float | None = None
    at_end: bool = True
    main_only: bool = False

    def due(self, end: StepEnd, minutes_passed: bool) -> bool:
        """Whether a hook of this cadence runs after ``end`` (``minutes_passed``: of every process)."""
        if self.at_end and end.last:
            return True
        return minutes_passed or (self.steps is not None and end.step % self.steps == 0)


class Timer:
    """Wall time (monotonic) since :meth:`reset`, against a number of minutes (None: never due)."""

    def __init__(self, minutes: float | None):
        self.minutes = minutes
        self.reset()

    def reset(self) -> None:
        self.since = time.monotonic()

    def passed(self) -> bool:
        return self.minutes is not None and time.monotonic() - self.since >= self.minutes * 60


class Hook(Protocol):
    """What the runner needs of a hook: when it runs, and what it does then. A hook that must
    see every step (to sum a window) also has ``observe(run, end)``, called after every step
    before the hook's own ``after_step``."""

    cadence: Cadence

    def after_step(self, run: Run, end: StepEnd) -> None: ...


class HookRunner:
    """The hooks of a fit, in order, each run when its :class:`Cadence` says.

    Time cadences must agree on every process (a checkpoint gathers from all of them), so the
    loop asks :meth:`minutes_passed` on each process, OR-s the answers over processes with its
    own stop flags (one all-reduce: :meth:`Dist.any`) and hands them to :meth:`after_step`.
    """

    def __init__(self, hooks: list):
        self.hooks = list(hooks)
        self._timers = [Timer(hook.cadence.minutes) for hook in self.hooks]

    def minutes_passed(self) -> list[bool]:
        """Per hook, whether its ``cadence.minutes`` have passed on this process."""
        return [timer.passed() for timer in self._timers]

    def after_step(self, run: Run, end: StepEnd, minutes_passed: list[bool]) -> None:
        """Each hook in order: ``observe`` (if it has one), then ``after_step`` when it is due."""
        for hook, timer, passed in zip(self.hooks, self._timers, minutes_passed, strict=True):
            observe = getattr(hook, "observe", None)
            if observe is not None:
                observe(run, end)
            if hook.cadence.due(end, passed) and (run.dist.main or not hook.cadence.main_only):
                hook.after_step(run, end)
                timer.reset()


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

    cadence = Cadence(steps=1)

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
    """The progress line after every step (:meth:`observe`); the window's mean loss terms, rate
    and schedule every ``train.log_every`` steps and after the last (``train/...``)."""

    SHOWN = ("loss", "adv", "render", "svbrdf", "d_loss")

    def __init__(self, run: Run):
        self.cadence = Cadence(steps=run.recipe.train.log_every)
        self.sums: dict[str, float] = {}
        self.count = 0
        self.window = (run.watch.seconds, 0)  # (training seconds, samples) since the last log
        self.rate = 0.0  # samples per second of training time in the window

    def observe(self, run: Run, end: StepEnd) -> None:
        for k, v in end.terms.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.count += 1
        seconds = run.watch.seconds
        self.window = (self.window[0], self.window[1] + end.samples)
        self.rate = self.window[1] / max(seconds - self.window[0], 1e-9)
        shown = {k: end.terms[k] for k in self.SHOWN if k in end.terms}
        run.progress.update(end.step, shown, self.rate, seconds)

    def after_step(self, run: Run, end: StepEnd) -> None:
        seconds = run.watch.seconds
        metrics = {f"train/{k}": v / self.count for k, v in self.sums.items()}
        metrics.update(
            {
                "train/lr": run.gan.g_opt.param_groups[0]["lr"],
                "train/samples_per_s": self.rate,
                "train/epoch": end.step / run.order.steps_per_epoch,
                "train/seconds": seconds,
            }
        )
        run.tracker.log_metrics(metrics, end.step)
        self.sums, self.count, self.window = {}, 0, (seconds, 0)


class Validation:
    """``val/`` (and ``val_real/``) metrics, with the training time so far so that curves can be
    drawn against time, and the sample grid as ``samples/step_N.png`` (main process)."""

    def __init__(self, run: Run):
        self.cadence = Cadence(steps=run.recipe.train.validate_every, main_only=True)
        self.metrics: dict[str, float] = {}  # the last validation's

    def after_step(self, run: Run, end: StepEnd) -> None:
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
        t = run.recipe.train
        self.cadence = Cadence(steps=t.checkpoint_every, minutes=t.checkpoint_minutes)
        self.upload = Timer(t.upload_minutes)  # checked when a checkpoint is written (main process)

    def after_step(self, run: Run, end: StepEnd) -> None:
        rngs = run.dist.gather(run.gan.rng_state())
        if run.dist.main:
            state = run.state(rngs)
            save_checkpoint(run.ckpt_path, state)
            if end.last or self.upload.passed():
                self._upload(run, state)
        run.dist.barrier()
        run.saved_at = end.step

    def _upload(self, run: Run, state: dict[str, Any]) -> None:
        weights = save_checkpoint(run.out / WEIGHTS_NAME, {k: state[k] for k in WEIGHT_FIELDS})
        run.tracker.log_artifact(weights, "checkpoints")
        self.upload.reset()
