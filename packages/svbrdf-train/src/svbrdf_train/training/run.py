"""One fit's run, and the narrow, read-only view of it that its hooks get.

:class:`Run` is everything a fit has (what it trains, with what, where it writes, how it
reports); only the trainer and the hook runner hold it. A hook sees a :class:`RunView`: a
frozen snapshot, taken after each step, of what hooks read (the step and its loss terms, the
clock, the recipe, the folder, the tracker and the terminal it reports to, the generator to
validate, the collective calls a checkpoint needs). Assigning one of its fields raises
:class:`dataclasses.FrozenInstanceError`; a hook returns a :class:`RunChange` for what it
changes, and :class:`~svbrdf_train.training.hooks.HookRunner` applies it to the run.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from torch import nn

from ..recipe import Recipe
from ..tracking import Tracker
from . import distributed
from .checkpoint import CHECKPOINT_NAME
from .clock import Stopwatch
from .order import BatchOrder
from .progress import Progress
from .schedule import LrSchedule
from .step import GanStep
from .validation import Validator

__all__ = ["Run", "StepEnd", "RunView", "RunChange"]


@dataclass(frozen=True)
class StepEnd:
    """One step as the loop hands it to the hook runner; the flags are the same on every process."""

    step: int
    terms: dict[str, float]
    samples: int  # of all processes
    last: bool  # the fit stops after this step


@dataclass(frozen=True)
class RunChange:
    """What a hook changes in the run, returned from its ``on_step`` (None: nothing).

    ``saved_at``: the step of the checkpoint the hook has just written (what a stopped fit says
    is kept, and resumes from)."""

    saved_at: int | None = None


@dataclass(frozen=True)
class RunView:
    """What a hook sees of the fit: after a step (:meth:`Run.view`), or before the first one
    when the hook is made (``terms`` empty, ``samples`` 0). Read-only: a hook returns a
    :class:`RunChange` instead of assigning. ``tracker`` and ``progress`` are where a hook
    reports; ``checkpoint_state`` and ``barrier`` are collective (every process calls them)."""

    step: int  # the steps made so far (of the whole fit, resumed or not)
    terms: Mapping[str, float]  # the step's loss terms (read-only)
    samples: int  # the step's samples, of all processes
    last: bool  # the fit stops after this step
    recipe: Recipe
    out: Path  # the fit's folder
    ckpt_path: Path  # out/last.pt
    main: bool  # the main process (rank 0): the one that logs
    total_steps: int  # the step budget
    steps_per_epoch: int
    start_step: int  # the step this session started (resumed) at
    saved_at: int  # the step of the last checkpoint written
    seconds: float  # training time so far (train.clock), resumed fits included
    pace: float | None  # seconds per step after the warm-up (Stopwatch.pace); None until known
    lr: float  # the generator's learning rate now
    schedule: LrSchedule  # the learning-rate schedule (its warnings)
    generator: nn.Module
    validator: Validator  # validator(generator): (metrics, sample grid)
    tracker: Tracker
    progress: Progress
    checkpoint_state: Callable[[], dict[str, Any] | None]  # gathers random states: the state on main
    weights_state: Callable[[], dict[str, Any]]  # this process's state without random states (not collective)
    barrier: Callable[[], None]


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

    def checkpoint_state(self) -> dict[str, Any] | None:
        """Every process's random state gathered (collective): :meth:`state` on the main process,
        None on the others."""
        rngs = self.dist.gather(self.gan.rng_state())
        return self.state(rngs) if self.dist.main else None

    def view(self, end: StepEnd | None = None) -> RunView:
        """What a hook sees after step ``end`` (None: now, before the next step)."""
        gan, order = self.gan, self.order
        if end is None:
            end = StepEnd(gan.step, {}, 0, last=False)
        return RunView(
            step=end.step, terms=MappingProxyType(end.terms), samples=end.samples, last=end.last,
            recipe=self.recipe, out=self.out, ckpt_path=self.ckpt_path, main=self.dist.main,
            total_steps=order.total_steps, steps_per_epoch=order.steps_per_epoch,
            start_step=self.start_step, saved_at=self.saved_at,
            seconds=self.watch.seconds, pace=self.watch.pace(), lr=gan.g_opt.param_groups[0]["lr"],
            schedule=gan.schedule, generator=gan.generator, validator=self.validator,
            tracker=self.tracker, progress=self.progress,
            checkpoint_state=self.checkpoint_state, weights_state=lambda: self.state([]),
            barrier=self.dist.barrier,
        )  # fmt: skip
