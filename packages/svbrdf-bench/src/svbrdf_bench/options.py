"""What ``svbrdf-bench run`` is asked to do (:class:`BenchOptions`), as the command line gives it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .presets import Preset
from .refinement import RefinePlan

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
    say: Callable[[str], None] = print
