"""Seeds and training budgets of a benchmark's fits: ``--seeds N`` trains N fits per model (seed s
in 0..N-1 set as ``train.seed`` and ``data.seed``, everything else equal), and ``--minutes 2,8,32``
or ``--steps 500,2000`` trains one fit per model and seed to the largest mark, saving its weights
at every mark (the trainer's snapshots), each then scored as a row of that model at that budget.

:class:`TrainBudget` is what each fit is told (:func:`train_budget` reads it from the flags);
:func:`row_label` names a row (``ours``, ``ours seed 1``, ``ours @ 8 min``,
``ours seed 1 @ 8 min``); :func:`check_overrides` refuses a ``--set`` of a field they set. The
rows one fit is scored as, and their child runs: :func:`svbrdf_bench.children.fit_rows`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .errors import BenchError
from .layout import budget_words

__all__ = [
    "TrainBudget",
    "parse_seeds",
    "parse_marks",
    "train_budget",
    "check_overrides",
    "row_label",
    "budget_text",
]


@dataclass(frozen=True)
class TrainBudget:
    """How long each fit trains: to the largest of ``marks``, in training minutes on the fit's clock
    (``kind`` ``minutes``) or in generator steps (``steps``); with several marks the fit saves its
    weights at each (``train.snapshot_minutes`` / ``snapshot_steps``) and each is a row. ``kind``
    None: each recipe's own schedule (the ``paper`` preset)."""

    kind: str | None = None
    marks: tuple[float, ...] = ()

    @property
    def curve(self) -> bool:
        """Several budgets: one fit, scored at each of its snapshots."""
        return len(self.marks) > 1

    def words(self, mark: float | None = None) -> str | None:
        """``8 min``, ``500 steps`` (the largest mark unless given); None: the recipe's schedule."""
        if self.kind is None:
            return None
        return budget_words(self.kind, self.marks[-1] if mark is None else mark)

    @property
    def param(self) -> str:
        """The parent run's ``train_budgets``: ``minutes 2,8,32``, ``steps 500``, ``recipe schedule``."""
        if self.kind is None:
            return "recipe schedule"
        return f"{self.kind} {','.join(f'{m:g}' for m in self.marks)}"

    @property
    def keys(self) -> tuple[str, ...]:
        """The recipe fields these budgets set: a ``--set`` of one of them would clash."""
        if self.kind is None:
            return ()
        return (f"train.max_{self.kind}", *((f"train.snapshot_{self.kind}",) if self.curve else ()))

    def fit_args(self) -> list[str]:
        """The ``svbrdf-train fit`` arguments: train to the largest mark, a snapshot at every mark."""
        if self.kind is None:
            return []
        top = self.marks[-1]
        args = ["--max-minutes", f"{top:g}"] if self.kind == "minutes" else ["--max-steps", str(int(top))]
        if self.curve:
            args += ["--set", f"train.snapshot_{self.kind}=[{', '.join(f'{m:g}' for m in self.marks)}]"]
        return args

    def snapshot(self, mark: float) -> str:
        """The file of the fit's snapshot at ``mark`` (``minutes-8.pt``, ``steps-500.pt``)."""
        from svbrdf_train import snapshot_name

        return snapshot_name(self.kind, int(mark) if self.kind == "steps" else float(mark))


# -- the flags --------------------------------------------------------------------------------


def parse_seeds(text: str | int) -> int:
    """``--seeds N``: a whole number >= 1."""
    try:
        seeds = int(str(text).strip())
    except ValueError:
        seeds = 0
    if seeds < 1 or str(seeds) != str(text).strip():
        raise BenchError(f"--seeds {text}: expected a whole number of fits per model >= 1, e.g. --seeds 3")
    return seeds


def parse_marks(flag: str, text: str, *, whole: bool) -> tuple[float, ...]:
    """``--minutes 2,8,32`` / ``--steps 500,2000``: increasing budgets > 0 (steps whole numbers);
    a single ``--minutes`` may be 0 (stop after the first step), as before."""
    example = f"e.g. {flag} {'500,2000' if whole else '2,8,32'}"
    items = [x.strip() for x in str(text).split(",")]
    values = []
    for item in items:
        try:
            value = float(item)
        except ValueError:
            raise BenchError(f"{flag} {text}: {item!r} is not a number; give budgets separated by commas, "
                             f"{example}") from None  # fmt: skip
        if not math.isfinite(value) or value < 0 or (whole and value != int(value)):
            what = "whole numbers of steps > 0" if whole else "minutes >= 0"
            raise BenchError(f"{flag} {text}: {item!r} is not one of the {what}; {example}")
        values.append(value)
    if len(values) > 1 and (0 in values or any(b <= a for a, b in zip(values, values[1:], strict=False))):
        raise BenchError(f"{flag} {text}: several budgets must be increasing and > 0, {example}")
    if whole and values == [0]:
        raise BenchError(f"{flag} {text}: a budget of 0 steps trains nothing; {example}")
    return tuple(values)


def train_budget(minutes: str | float | None, steps: str | None, preset_minutes: float | None) -> TrainBudget:
    """The budgets of ``--minutes`` or ``--steps`` (never both), else the preset's minutes (None:
    each recipe's own schedule)."""
    if minutes is not None and steps is not None:
        raise BenchError(
            f"--minutes {minutes} and --steps {steps} both given; give one: equal training time "
            "(--minutes 2,8,32) or equal steps (--steps 500,2000)"
        )
    if steps is not None:
        return TrainBudget("steps", parse_marks("--steps", steps, whole=True))
    if minutes is not None:
        return TrainBudget("minutes", parse_marks("--minutes", str(minutes), whole=False))
    return TrainBudget() if preset_minutes is None else TrainBudget("minutes", (float(preset_minutes),))


def check_overrides(overrides: Sequence[str], budget: TrainBudget, seeds: int) -> None:
    """Refuse a ``--set`` of a field the seeds or the budgets set for every fit (the fit would
    refuse the clash after the benchmark started)."""
    keys = {item.partition("=")[0].strip(): item for item in overrides}
    owned = [(k, f"--seeds {seeds} sets it to each fit's seed") for k in ("train.seed", "data.seed")
             if seeds > 1]  # fmt: skip
    flag = "--steps" if budget.kind == "steps" else "--minutes (or the preset)"
    owned += [(k, f"{flag} sets it ({budget.param})") for k in budget.keys]
    for key, why in owned:
        if key in keys:
            raise BenchError(f"--set {keys[key]}: {why}; leave it out of --set")


def row_label(model: str, seed: int | None, budget: str | None) -> str:
    """A row's label: ``ours``; ``ours seed 1`` (``seed`` None: the model has one fit);
    ``ours @ 8 min`` (``budget`` None: one budget); ``ours seed 1 @ 8 min``."""
    label = model if seed is None else f"{model} seed {seed}"
    return label if budget is None else f"{label} @ {budget}"


def budget_text(budget: TrainBudget, seeds: int, trained: bool, reused: bool, refs: bool) -> tuple[str, str]:
    """The training budget of a benchmark as its parent's param (never starting with a digit but
    for a single number of minutes, which the report reads as such), and in words; ``trained``,
    ``reused``, ``refs``: whether it trains fits, reuses fits, scores reference model files."""
    if budget.curve and (trained or reused):
        unit = "min of training" if budget.kind == "minutes" else "steps"
        param = words = (f"budgets of {', '.join(f'{m:g}' for m in budget.marks)} {unit}, each the "
                         "snapshot of one fit per model and seed")  # fmt: skip
    elif trained and budget.kind is None:
        param, words = "recipe schedule", "each recipe's full schedule"
    elif trained and budget.kind == "steps":
        param = words = f"equal steps: {budget.marks[0]:g} per model"
    elif trained:
        param, words = str(budget.marks[0]), f"{budget.marks[0]:g} min of training per model"
    elif reused:
        param = "reused fits, each with its own training budget (see the time table)"
        words = "reused fits, each with its own training budget"
    else:
        param = words = "reference models only, each with the training budget its file records"
    if seeds > 1 and (trained or reused):
        words += f"; {seeds} seeds per model"
    if refs and (trained or reused):
        words += "; reference rows: their own budgets, not equal"
    return param, words
