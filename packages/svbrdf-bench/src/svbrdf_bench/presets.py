"""Benchmark presets: how long each model trains, on how many test images, where inference is
timed, and what that costs.

Every model of one invocation gets the same training-time budget (``minutes``, training time
without validation), so the comparison is at equal cost; ``paper`` instead trains each recipe
for its full schedule (20 epochs), as the paper did.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import BenchError

__all__ = ["Preset", "PRESETS", "get_preset", "TEST_SEED"]

#: Seed of the default procedural test set: apart from every training (0) and validation (1) seed.
TEST_SEED = 20_221
#: The latency grid of the presets that run on a GPU: 256, 512 and 1024 px, batch 1 and 8.
FULL_GRID = "256x1,256x8,512x1,512x8,1024x1,1024x8"


@dataclass(frozen=True)
class Preset:
    name: str
    size: str
    """Recipe size the models train at (``svbrdf-train fit --size``)."""
    minutes: float | None
    """Training-time budget per model; None trains the recipe's whole schedule."""
    test_count: int
    """Images of the default procedural test set."""
    validate_every: int
    """Validation period in steps: the points of the learning curves."""
    latency_repeats: int
    """Timed inference runs per model, after 3 warm-up runs: the median and interquartile range
    are reported (quartiles of fewer than about 20 runs move with a single outlier)."""
    expected: str
    """What the preset takes, for the help text and the report."""
    overrides: tuple[str, ...] = ()
    """Recipe overrides (``section.field=value``) for every model, before the user's ``--set``."""
    latency_grid: str = FULL_GRID
    """Image sizes x batches each row's inference is timed at (``--latency-grid`` syntax;
    :mod:`svbrdf_bench.inference`); 256x1 is always timed, with ``latency_repeats`` runs."""
    grid_repeats: int = 10
    """Timed runs per grid point but 256x1, after 2 warm-up runs (the median is reported)."""


#: The presets by name.
PRESETS = {
    p.name: p
    for p in (
        Preset(
            "quick", size="cpu", minutes=2.0, test_count=32, validate_every=25, latency_repeats=50,
            expected="under 10 min for two models on a 2-core CPU (2 min of training each)",
            # The cpu size's 2 epochs of 2000 samples end before 2 minutes for the faster models,
            # and then the budgets would not be equal: 10x the samples lets the clock decide.
            overrides=("data.count=20000",),
            # The grid's small corner: about 3 s per cpu-size model on an idle core (7 runs of
            # 256x8 and of 512x1); 1024x8 alone is 128x the 256 px latency, ~2.5 s a run for ours.
            latency_grid="256x1,256x8,512x1", grid_repeats=5,
        ),
        Preset(
            "standard", size="paper", minutes=30.0, test_count=256, validate_every=250, latency_repeats=100,
            expected="about 35 min per model on one H100 (30 min of training each); days on a CPU",
        ),
        Preset(
            "paper", size="paper", minutes=None, test_count=1000, validate_every=2000, latency_repeats=200,
            expected="the paper's 20 epochs: 4-7.5 h per model on one H100 (svbrdf README), weeks on a CPU",
        ),
    )
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise BenchError(f"unknown preset {name!r}; presets: {', '.join(PRESETS)}")
    return PRESETS[name]
