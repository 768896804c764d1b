"""Learning-rate schedules counted in samples seen, so they mean the same on any data set.

The paper halves Adam's rate "every 2 epochs" of its 200k procedural samples: every 400k
samples. Counted in epochs, the same words halve the rate every 4 steps on a folder of 17
real strips at batch 4, and the network stops learning within a minute. So the recipe's
period is ``optim.decay_every_samples``; ``optim.decay_every_epochs`` stays as an option for
those who want the old meaning (it is the same thing only on the paper's data).

The factor applied to ``optim.lr`` and ``optim.d_lr`` after ``n`` samples (all processes
together) is::

    factor(n) = min(1, (n + 1) / warmup_samples) * decay ** floor(n / period)

a linear warm-up (none when ``warmup_samples`` is 0) and a step decay (none when neither
period is set, or ``decay`` is 1). It is a function of the step alone, so a resumed fit needs
no saved scheduler state to go on exactly where it stopped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch

__all__ = ["DecaySettings", "LrSchedule", "ScheduledRate", "WARN_BELOW", "WARN_WITHIN", "optimiser_of"]

#: The fit warns when its rate would fall below this fraction of its start ...
WARN_BELOW = 0.01
#: ... within this fraction of its budget.
WARN_WITHIN = 0.1


class DecaySettings(Protocol):
    """What a schedule reads of the recipe's ``optim`` section
    (:class:`svbrdf_train.recipe.OptimSection`: ``LrSchedule(optim, per_step, samples_per_epoch)``)."""

    decay: float
    decay_every_samples: int | None
    decay_every_epochs: int | None
    warmup_samples: int


@dataclass(frozen=True)
class LrSchedule:
    """The rate factor of a fit: ``optim``'s settings, ``per_step`` samples a step (batch x
    processes) and ``samples_per_epoch`` (what an epoch period means)."""

    optim: DecaySettings
    per_step: int
    samples_per_epoch: int

    @property
    def period(self) -> int | None:
        """Samples between two decay steps; None: no decay."""
        o = self.optim
        if o.decay == 1:
            return None
        if o.decay_every_epochs is not None:
            return o.decay_every_epochs * self.samples_per_epoch
        return o.decay_every_samples

    def samples(self, step: int) -> int:
        return step * self.per_step

    def factor(self, step: int) -> float:
        """The factor on the base rates for the generator step ``step`` (0-based)."""
        n = self.samples(step)
        f = 1.0
        if self.optim.warmup_samples > 0:
            f = min(1.0, (n + self.per_step) / self.optim.warmup_samples)
        period = self.period
        if period is not None:
            f *= self.optim.decay ** (n // period)
        return f

    def first_step_below(self, fraction: float) -> int | None:
        """The first step whose factor is below ``fraction`` (after any warm-up); None: never."""
        period = self.period
        if period is None:
            return None
        # decay ** k < fraction for the first k = floor(log(fraction) / log(decay)) + 1
        k = math.floor(math.log(fraction) / math.log(self.optim.decay)) + 1
        step = math.ceil(k * period / self.per_step)
        while self.factor(step) >= fraction:  # a warm-up longer than the decay: later still
            step += max(1, math.ceil(period / self.per_step))
        return step

    def cause(self) -> str:
        """The setting that sets the decay period, as a user would write it."""
        o = self.optim
        if o.decay_every_epochs is not None:
            return (
                f"optim.decay_every_epochs={o.decay_every_epochs} (an epoch is "
                f"{self.samples_per_epoch} samples, {max(1, self.samples_per_epoch // self.per_step)} "
                "steps, here)"
            )
        return f"optim.decay_every_samples={o.decay_every_samples}"

    def warning(self, budget_steps: int, what: str) -> str | None:
        """A one-paragraph warning when the rate falls below :data:`WARN_BELOW` of its start
        within :data:`WARN_WITHIN` of ``budget_steps`` (``what`` says how the budget was
        found), else None."""
        step = self.first_step_below(WARN_BELOW)
        if step is None or step > WARN_WITHIN * budget_steps:
            return None
        fix = (
            "count the period in samples instead (--set optim.decay_every_epochs=null "
            f"--set optim.decay_every_samples=N, N near a third of the {budget_steps * self.per_step} "
            "samples of the budget)"
            if self.optim.decay_every_epochs is not None
            else "raise optim.decay_every_samples (a third of the budget's "
            f"{budget_steps * self.per_step} samples halves the rate 3 times)"
        )
        return (
            f"warning: the learning rate falls below {WARN_BELOW:.0%} of optim.lr at step {step}, "
            f"{step / budget_steps:.1%} of the budget of {budget_steps} steps ({what}): "
            f"{self.cause()} with optim.decay={self.optim.decay:g} does it, and the network will "
            f"barely learn after that; {fix}, or set optim.decay=1 for a constant rate"
        )


@dataclass(frozen=True)
class ScheduledRate:
    """One optimiser's learning rate along a schedule: ``base x schedule.factor(step)``.

    :func:`optimiser_of` returns it with its optimiser. :meth:`at` sets the rate of a generator
    step before the step runs, so the optimiser holds, after the step, the rate the step used
    (what the fit logs as ``train/lr``); a resumed fit sets it from its step alone.
    """

    optimiser: torch.optim.Optimizer
    base: float
    schedule: LrSchedule

    def at(self, step: int) -> float:
        """Set the rate of every parameter group for generator step ``step``; return it."""
        rate = self.base * self.schedule.factor(step)
        for group in self.optimiser.param_groups:
            group["lr"] = rate
        return rate


def optimiser_of(optim, params, schedule: LrSchedule, *, discriminator: bool = False):
    """``(Adam, ScheduledRate)``: Adam over ``params`` with the recipe's ``optim`` section's
    ``betas``, and the rate it follows: ``lr`` (``d_lr`` for the ``discriminator``) times the
    section's ``batch_factor`` times ``schedule``'s factor (``LrSchedule(optim, per_step,
    samples_per_epoch)``), set for each step by the returned rate (``rate.at(step)``)."""
    base = (optim.d_lr if discriminator else optim.lr) * optim.batch_factor(schedule.per_step)
    optimiser = torch.optim.Adam(params, lr=base, betas=tuple(optim.betas))
    return optimiser, ScheduledRate(optimiser, base, schedule)
