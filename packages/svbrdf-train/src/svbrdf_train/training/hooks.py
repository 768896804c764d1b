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
KeepBest           after each validation, main process    with ``train.keep_best``: the weights
                   only                                   to ``OUT/best.pt`` when its metric is
                                                          the lowest so far; ``best/...``
                                                          metrics; best.pt to MLflow at the end
Snapshots          after every step, main process only    with ``train.snapshot_minutes`` or
                                                          ``snapshot_steps``: the weights when
                                                          the training time or step first
                                                          reaches each mark, to
                                                          ``OUT/snapshots/`` and MLflow
=================  =====================================  ======================================

Every hook also runs after the last step (``RunView.last``: the step budget, the time budget
or a stop request), so a fit that ends early still logs its last window. A hook is any object
with a ``cadence`` and ``on_step(view)`` (and, if it must see every step, ``observe(view)``);
it is made with the view before the first step. The view (:class:`~svbrdf_train.training.run.RunView`)
is narrow and read-only: what hooks read of the run, never the run itself. ``on_step`` returns
what it changes, a :class:`~svbrdf_train.training.run.RunChange` (or None), and
:class:`HookRunner`, the one place that decides after each step which hooks run, applies it to
the run. The earlier design, ``after_step(run, end)`` given the whole run, went in 0.2.0: such
a hook is refused with what to write instead.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from .checkpoint import BEST_NAME, SNAPSHOTS_DIR, WEIGHTS_NAME, save_checkpoint
from .progress import format_duration
from .run import Run, RunChange, RunView, StepEnd

__all__ = [
    "Cadence", "Timer", "Hook", "HookRunner", "BudgetWarning", "Logging", "Validation", "Checkpoints",
    "KeepBest", "Snapshots", "snapshot_name",
]  # fmt: skip
#: Checkpoint fields a user of the weights needs (predict, --init); the rest is for resuming.
WEIGHT_FIELDS = (
    "recipe", "step", "epoch", "generator", "discriminator", "run_id", "init",
    "train_seconds", "wall_seconds", "world_size", "made_with",
)  # fmt: skip


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
    """What the runner needs of a hook: when it runs, and what it does then, given the read-only
    view of the run, returning what it changes (None: nothing). A hook that must see every step
    (to sum a window) also has ``observe(view)``, called after every step before the hook's
    own ``on_step``; it changes nothing."""

    cadence: Cadence

    def on_step(self, view: RunView) -> RunChange | None: ...


def _check_hook(hook: Any) -> None:
    """Refuse a hook without ``on_step(view)``, naming the earlier design where it has that."""
    if hasattr(hook, "on_step"):
        return
    if hasattr(hook, "after_step"):
        raise TypeError(
            f"hook {type(hook).__name__} has after_step(run, end), which went in 0.2.0: define "
            "on_step(view) (and observe(view)) on the read-only RunView, and return a RunChange for what "
            "it changes (svbrdf_train.training.hooks)"
        )
    raise TypeError(f"hook {type(hook).__name__} has no on_step(view): a hook is a cadence and on_step")


class HookRunner:
    """The hooks of a fit, in order, each run when its :class:`Cadence` says, with the view of
    the run after the step; what a hook returns is applied to the run before the next hook.

    Time cadences must agree on every process (a checkpoint gathers from all of them), so the
    loop asks :meth:`minutes_passed` on each process, OR-s the answers over processes with its
    own stop flags (one all-reduce: :meth:`Dist.any`) and hands them to :meth:`after_step`.
    """

    def __init__(self, hooks: list):
        self.hooks = list(hooks)
        self._timers = [Timer(hook.cadence.minutes) for hook in self.hooks]
        for hook in self.hooks:
            _check_hook(hook)

    def minutes_passed(self) -> list[bool]:
        """Per hook, whether its ``cadence.minutes`` have passed on this process."""
        return [timer.passed() for timer in self._timers]

    def after_step(self, run: Run, end: StepEnd, minutes_passed: list[bool]) -> None:
        """Each hook in order: ``observe`` (if it has one), then ``on_step`` when it is due."""
        view = run.view(end)
        for hook, timer, passed in zip(self.hooks, self._timers, minutes_passed, strict=True):
            observe = getattr(hook, "observe", None)
            if observe is not None:
                observe(view)
            if not hook.cadence.due(end, passed) or (hook.cadence.main_only and not view.main):
                continue
            if (change := hook.on_step(view)) is not None:
                _apply(run, hook, change)
                view = run.view(end)  # the next hooks see the run as it is now
            timer.reset()


def _apply(run: Run, hook: Hook, change: Any) -> None:
    """What a hook returned, applied to the run."""
    if not isinstance(change, RunChange):
        raise TypeError(f"{type(hook).__name__}.on_step returned {change!r}: a RunChange or None")
    if change.saved_at is not None:
        run.saved_at = change.saved_at


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

    def __init__(self, view: RunView):
        self.done = view.recipe.train.max_minutes is None  # a step budget is known now
        self.time_checked = self.done
        if self.done:
            self._warn(view, view.total_steps, "the step budget")

    def on_step(self, view: RunView) -> None:
        if not self.time_checked:
            self._time_budget(view)
        pace = view.pace
        if self.done or pace is None or pace <= 0:
            return
        minutes = view.recipe.train.max_minutes
        steps = min(view.total_steps, view.step + int((minutes * 60 - view.seconds) / pace))
        self._warn(view, steps, f"{minutes:g} min at {pace * 1000:.0f} ms/step")
        self.done = True

    def _time_budget(self, view: RunView) -> None:
        """Warn when the step budget ends the fit in under half of ``train.max_minutes``."""
        t, pace, seconds = view.recipe.train, view.pace, view.seconds
        per_step = pace if pace is not None else seconds / max(1, view.step)
        self.time_checked = pace is not None or view.last
        left = view.total_steps - view.step
        if view.last or per_step <= 0 or seconds + left * per_step >= 0.5 * t.max_minutes * 60:
            return
        self.time_checked = True
        if view.total_steps == t.max_steps:
            steps, fix = f"train.max_steps={t.max_steps}", "raise --max-steps (or leave it out)"
        else:
            steps = f"train.epochs={t.epochs} of {view.steps_per_epoch} steps"
            fix = "raise train.epochs (--set train.epochs=N)"
        text = (
            f"warning: the time budget (train.max_minutes={t.max_minutes:g}) will not be reached: the "
            f"step budget of {view.total_steps} steps ({steps}) ends the fit after about "
            f"{format_duration(seconds + left * per_step)} of training; {fix} to train for "
            "the whole time"
        )
        if view.main:
            view.progress.message(text)
            view.tracker.set_tags({"svbrdf.warning.time_budget": text[:5000]})

    @staticmethod
    def _warn(view: RunView, steps: int, what: str) -> bool:
        text = view.schedule.warning(steps, what)
        if text is None:
            return False
        if view.main:
            view.progress.message(text)
            view.tracker.set_tags({"svbrdf.warning": text[:5000]})
        return True


class Logging:
    """The progress line after every step (:meth:`observe`); the window's mean loss terms, rate
    and schedule every ``train.log_every`` steps and after the last (``train/...``)."""

    SHOWN = ("loss", "adv", "render", "svbrdf", "d_loss")

    def __init__(self, view: RunView):
        self.cadence = Cadence(steps=view.recipe.train.log_every)
        self.sums: dict[str, float] = {}
        self.count = 0
        self.window = (view.seconds, 0)  # (training seconds, samples) since the last log
        self.rate = 0.0  # samples per second of training time in the window

    def observe(self, view: RunView) -> None:
        for k, v in view.terms.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.count += 1
        seconds = view.seconds
        self.window = (self.window[0], self.window[1] + view.samples)
        self.rate = self.window[1] / max(seconds - self.window[0], 1e-9)
        shown = {k: view.terms[k] for k in self.SHOWN if k in view.terms}
        view.progress.update(view.step, shown, self.rate, seconds)

    def on_step(self, view: RunView) -> None:
        seconds = view.seconds
        metrics = {f"train/{k}": v / self.count for k, v in self.sums.items()}
        metrics.update(
            {
                "train/lr": view.lr,
                "train/samples_per_s": self.rate,
                "train/epoch": view.step / view.steps_per_epoch,
                "train/seconds": seconds,
            }
        )
        view.tracker.log_metrics(metrics, view.step)
        self.sums, self.count, self.window = {}, 0, (seconds, 0)


class Validation:
    """``val/`` (and ``val_real/``) metrics, with the training time so far so that curves can be
    drawn against time, and the sample grid as ``samples/step_N.png`` (main process)."""

    def __init__(self, view: RunView):
        self.cadence = Cadence(steps=view.recipe.train.validate_every, main_only=True)
        self.metrics: dict[str, float] = {}  # the last validation's

    def on_step(self, view: RunView) -> None:
        metrics, grid = view.validator(view.generator)
        if metrics:
            view.tracker.log_metrics({**metrics, "val/train_seconds": view.seconds}, view.step)
        if grid is not None:
            from svbrdf_render import write_image

            path = write_image(view.out / "samples" / f"step_{view.step:07d}.png", grid)
            view.tracker.log_artifact(path, "samples")
            view.tracker.log_image(path, "samples", view.step)  # the same grid, with a step slider
        self.metrics = metrics


class Checkpoints:
    """The full state to ``OUT/last.pt`` (every process's random state gathered to the main
    one), and the weights alone to ``OUT/weights.pt`` and the MLflow run, less often; it
    returns the step saved (:attr:`RunChange.saved_at`).

    A checkpoint is written every ``train.checkpoint_every`` steps, when
    ``train.checkpoint_minutes`` of wall time have passed since the last one, and after the last
    step. The weights go to MLflow (``checkpoints/weights.pt``) after the last step and when
    ``train.upload_minutes`` have passed since the last upload: a paper-size checkpoint with
    both Adam states is about three times the weights, and MLflow keeps every upload's bytes
    until the run is deleted.
    """

    def __init__(self, view: RunView):
        t = view.recipe.train
        self.cadence = Cadence(steps=t.checkpoint_every, minutes=t.checkpoint_minutes)
        self.upload = Timer(t.upload_minutes)  # checked when a checkpoint is written (main process)

    def on_step(self, view: RunView) -> RunChange:
        state = view.checkpoint_state()  # every process; None but on the main one
        if state is not None:
            save_checkpoint(view.ckpt_path, state)
            if view.last or self.upload.passed():
                self._upload(view, state)
        view.barrier()
        return RunChange(saved_at=view.step)

    def _upload(self, view: RunView, state: dict[str, Any]) -> None:
        weights = save_checkpoint(view.out / WEIGHTS_NAME, {k: state[k] for k in WEIGHT_FIELDS})
        view.tracker.log_artifact(weights, "checkpoints")
        self.upload.reset()


class KeepBest:
    """With ``train.keep_best`` (a validation metric, lower is better): after each validation,
    the weights to ``OUT/best.pt`` (weights.pt's form, plus ``best``: metric, value, step) when
    the metric is the lowest so far, and ``best/value`` and ``best/step`` to the tracker; at the
    end, ``best.pt`` to the MLflow run (``checkpoints/best.pt``) and the run's tags
    ``svbrdf.best_step`` and ``svbrdf.best_value``. A fit that overfits then ships its best
    step: ``svbrdf-train export OUT/best.pt``.

    A resumed fit goes on from the best that ``best.pt`` records when it belongs to the same
    MLflow run (or both have none); a new fit in the folder starts afresh over it.
    Runs after :class:`Validation` and reads its metrics."""

    def __init__(self, view: RunView, validation: Validation):
        self.metric = view.recipe.train.keep_best
        self.validation = validation
        self.cadence = Cadence(steps=view.recipe.train.validate_every, main_only=True)
        self.best: dict[str, Any] | None = None
        if self.metric and view.start_step > 0:
            self.best = _recorded_best(view.out / BEST_NAME, view.weights_state().get("run_id"), self.metric)

    def on_step(self, view: RunView) -> None:
        if not self.metric:
            return
        value = self.validation.metrics.get(self.metric)
        if value is not None and value == value and (self.best is None or value < self.best["value"]):
            self.best = {"metric": self.metric, "value": float(value), "step": view.step}
            state = view.weights_state()
            save_checkpoint(view.out / BEST_NAME, {**{k: state[k] for k in WEIGHT_FIELDS}, "best": self.best})
            view.tracker.log_metrics({"best/value": self.best["value"], "best/step": view.step}, view.step)
        if view.last and self.best is not None and (view.out / BEST_NAME).is_file():
            view.tracker.log_artifact(view.out / BEST_NAME, "checkpoints")
            view.tracker.set_tags(
                {"svbrdf.best_metric": self.metric, "svbrdf.best_step": str(self.best["step"]),
                 "svbrdf.best_value": f"{self.best['value']:.6g}"}
            )  # fmt: skip


def snapshot_name(kind: str, mark: float) -> str:
    """The file of the snapshot at ``mark`` (``kind``: ``minutes`` or ``steps``):
    ``minutes-2.pt``, ``minutes-0.5.pt``, ``steps-1000.pt``."""
    return f"{kind}-{mark:g}.pt"


class Snapshots:
    """With ``train.snapshot_minutes`` / ``train.snapshot_steps``: the weights (weights.pt's
    form, plus ``snapshot``: kind, mark, step, training seconds) to
    ``OUT/snapshots/minutes-M.pt`` or ``steps-N.pt`` after the first step at which the
    training time (``train.clock``, as ``train.max_minutes`` counts it) or the step count
    reaches each mark, uploaded to the MLflow run (``snapshots/``) with the metrics
    ``snapshot/minutes-M`` = the step taken. A resumed fit takes only the marks it has not
    reached; a mark the fit never reaches has no file. One fit then answers "how good after 2,
    8 and 32 minutes" without a fit per budget."""

    cadence = Cadence(steps=1, main_only=True)

    def __init__(self, view: RunView):
        t = view.recipe.train
        self.marks = [("minutes", float(m)) for m in sorted(t.snapshot_minutes or ())]
        self.marks += [("steps", int(m)) for m in sorted(t.snapshot_steps or ())]
        if view.start_step > 0:  # resumed: what the fit already passed was taken (or missed) then
            self.marks = [(k, m) for k, m in self.marks if not self._reached(k, m, view)]

    @staticmethod
    def _reached(kind: str, mark: float, view: RunView) -> bool:
        return view.seconds >= mark * 60 if kind == "minutes" else view.step >= mark

    def on_step(self, view: RunView) -> None:
        due = [(k, m) for k, m in self.marks if self._reached(k, m, view)]
        if not due:
            return
        state = view.weights_state()
        for kind, mark in due:
            record = {"kind": kind, "mark": mark, "step": view.step, "seconds": view.seconds}
            path = view.out / SNAPSHOTS_DIR / snapshot_name(kind, mark)
            save_checkpoint(path, {**{k: state[k] for k in WEIGHT_FIELDS}, "snapshot": record})
            view.tracker.log_artifact(path, SNAPSHOTS_DIR)
            view.tracker.log_metrics({f"snapshot/{Path(path).stem}": view.step}, view.step)
            self.marks.remove((kind, mark))


def _recorded_best(path, run_id: str | None, metric: str) -> dict[str, Any] | None:
    """The ``best`` record of ``path`` when it belongs to run ``run_id`` and ranks by ``metric``."""
    from ..errors import CheckpointError
    from .checkpoint import load_checkpoint

    if not Path(path).is_file():
        return None
    try:
        state = load_checkpoint(path, check=False)
    except (OSError, CheckpointError):  # unreadable: the next validation writes a new best
        return None
    best = state.get("best") if isinstance(state, dict) else None
    if not isinstance(best, dict) or best.get("metric") != metric or state.get("run_id") != run_id:
        return None
    return best
