"""What ``svbrdf-bench run`` is asked to do (:class:`BenchOptions`), as the command line gives it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .presets import Preset
from .published import Published
from .refinement import RefinePlan
from .seeding import TrainBudget, train_budget

__all__ = ["BenchOptions", "BASELINES"]

#: The baselines every benchmark evaluates unless told not to (svbrdf_models.networks.baselines).
BASELINES = ("mean", "photo")


@dataclass
class BenchOptions:
    """The options of one benchmark (``svbrdf-bench run``'s flags)."""

    models: list[str]
    """Recipes to train; ``pretrained[:NAME]`` items are scored as reference rows instead."""
    preset: Preset
    from_runs: list[str] = field(default_factory=list)
    from_models: list[str] = field(default_factory=list)
    """Model files (any :func:`svbrdf_models.load_model` source) scored as reference rows."""
    allow_trained_strips: bool = False
    """Score a reference model even on test strips its provenance says it trained on."""
    test_data: str | None = None
    real_data: str | None = None
    """A folder of real flash photos (no ground truth): adds each model's self-consistency."""
    real_encoding: str = "srgb"
    real_pattern: str = "*"
    test_count: int | None = None
    minutes: float | None = None
    overrides: list[str] = field(default_factory=list)
    out: Path = Path("bench-report")
    device: str = "cpu"
    experiment: str = "svbrdf-bench"
    size: str | None = None
    """Recipe size instead of the preset's (``smoke`` for a dry run)."""
    baselines: list[str] = field(default_factory=lambda: list(BASELINES))
    """Registered generators evaluated untrained beside the models (``[]``: none)."""
    refine: RefinePlan = field(default_factory=RefinePlan)
    """Refinement budgets: a row per scored row and budget > 0 (default: none)."""
    group_by: str = "auto"
    """How real test samples are grouped into materials (svbrdf_train.GROUP_BY)."""
    latency_grid: tuple = ()
    """Image sizes x batches inference is timed at (``--latency-grid``, parsed by
    :func:`svbrdf_bench.inference.parse_latency_grid`); empty: the preset's."""
    seeds: int = 1
    """Fits per model (``--seeds N``): seed s in 0..N-1 set as ``train.seed`` and ``data.seed``."""
    budget: TrainBudget | None = None
    """Training budgets (``--minutes 2,8,32``, ``--steps 500,2000``); None: ``minutes`` or the preset's."""
    published: Published | None = None
    """Published numbers set beside the rows (``--published FILE.yaml``), checked; None: none."""
    say: Callable[[str], None] = print

    def train_budget(self) -> TrainBudget:
        """How long each fit trains: :attr:`budget`, else :attr:`minutes`, else the preset's."""
        if self.budget is not None:
            return self.budget
        return train_budget(self.minutes, None, self.preset.minutes)

    def latency_points(self) -> tuple:
        """Where each row's inference is timed: :attr:`latency_grid`, else the preset's."""
        from .inference import parse_latency_grid

        return self.latency_grid or parse_latency_grid(self.preset.latency_grid, "the preset's latency grid")
