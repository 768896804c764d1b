"""One row of a benchmark report (:class:`ModelEntry`: a trained model, a reference model file, a
baseline or a refined row) and the columns every table shares.

A row's figures are what its MLflow child run recorded: per-sample values (``per_sample``, the
accuracy tables' input) and single figures (``figures``: times, sizes, memory).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from svbrdf_render import MAP_NAMES

from ..layout import SECONDS_PER_IMAGE, STEPS_METRIC, STEPS_WALL_METRIC, budget_words

__all__ = [
    "COLUMNS",
    "METRICS",
    "REFERENCE",
    "PURE_OPTIMISATION",
    "CLOCK_WORDS",
    "TIME_COLUMNS",
    "SPREADS",
    "INHERITED",
    "ModelEntry",
]

COLUMNS = (*MAP_NAMES, "render")
METRICS = (
    ("rmse", "RMSE", "lower is better"),
    (
        "ssim",
        "SSIM (Wang et al. 2004: Gaussian window sigma 1.5, no sample covariance, data range 1)",
        "higher is better",
    ),
    ("lpips", "LPIPS", "lower"),
)
#: The baseline every trained model is held against, map by map.
REFERENCE = "mean"
#: How the report names ``mean`` refined: refinement from constant maps, optimisation alone.
PURE_OPTIMISATION = "pure-optimisation baseline"
#: How the report names the clock a fit's training time was budgeted on (tag svbrdf.clock).
CLOCK_WORDS = {
    "cpu": "CPU clock (process CPU time divided by torch threads)",
    "wall": "wall clock",
    "cuda": "GPU clock (wall time with the device synchronised)",
}
TIME_COLUMNS = (
    ("time/train_s", "train time, budget clock (s)", "{:.1f}"),
    (STEPS_WALL_METRIC, "train wall (s)", "{:.1f}"),
    (STEPS_METRIC, "steps", "{:.0f}"),
    ("time/train_samples_per_s", "train samples/s", "{:.1f}"),
    ("time/train_ms_per_step", "train ms/step [IQR]", "{:.0f}"),
    ("time/latency_ms", "latency 256px (ms) [IQR]", "{:.1f}"),
    ("model/params", "params (M)", "{:.2f}"),
    ("memory/peak_rss_mb", "peak RSS (MB)", "{:.0f}"),
    ("memory/peak_cuda_mb", "peak GPU (MB)", "{:.0f}"),
    (SECONDS_PER_IMAGE, "s/image (net + refine)", "{:.3g}"),
)
#: Time columns shown as median [IQR]: column -> (the median's figure, the IQR's figure); a row
#: without the IQR (an older run) shows the column's own figure alone.
SPREADS = {
    "time/latency_ms": ("time/latency_ms", "time/latency_iqr_ms"),
    "time/train_ms_per_step": ("time/train_ms_per_step_median", "time/train_ms_per_step_iqr"),
}
#: Figures a refined row shows from the row it refined (the same model, the same training).
INHERITED = ("time/train_s", STEPS_WALL_METRIC, STEPS_METRIC, "time/train_samples_per_s",
             "time/train_ms_per_step", "time/train_ms_per_step_median", "time/train_ms_per_step_iqr",
             "memory/peak_rss_mb", "memory/peak_cuda_mb")  # fmt: skip


@dataclass
class ModelEntry:
    """One row of the report: its label, its MLflow child run and the fit behind it, its
    per-sample values (``{"rmse/render": array over test samples, ...}``) and its figures."""

    label: str
    run_id: str
    train_run_id: str
    per_sample: dict[str, np.ndarray]
    figures: dict[str, float]
    curve: tuple[list[float], list[float]] = field(default_factory=lambda: ([], []))
    #: The same validation figure on real materials (the trainer's ``val_real/``), when logged.
    curve_real: tuple[list[float], list[float]] = field(default_factory=lambda: ([], []))
    #: An untrained baseline (tag svbrdf.baseline), not a trained model.
    baseline: bool = False
    #: The clock the fit's training time was budgeted on (tag svbrdf.clock); None: not recorded.
    clock: str | None = None
    #: Where a fine-tuned fit's starting weights came from (``fit --init``), and the training
    #: time behind them (its curves are shifted by it); None: trained from scratch.
    init: tuple[str, float] | None = None
    #: A reference row (a model file trained elsewhere, not at the benchmark's budget): its short
    #: name (tag svbrdf.reference); None for models trained or reused here and for baselines.
    reference_name: str | None = None
    #: Of a reference row: its source, SHA-256 and the budget its file records (``budget.*`` params).
    budget: dict[str, str] = field(default_factory=dict)
    #: Of a refined row (``--refine``): its budget in Adam steps; 0 for the row as scored.
    refine_steps: int = 0
    #: Of a refined row: the child run of the row it refined, and that row's label.
    refined_from: str | None = None
    base_label: str | None = None
    #: Of a fit's row: its seed (tag svbrdf.seed), the model it is a seed or budget of (tag
    #: svbrdf.method) and its training budget, ``("minutes", 8.0)`` (tag svbrdf.budget); None: not
    #: recorded (older runs, baselines, reference rows). See :mod:`svbrdf_bench.report.seeds`.
    seed: int | None = None
    method: str | None = None
    train_budget: tuple[str, float] | None = None

    @property
    def budget_text(self) -> str:
        """The row's training budget, ``8 min`` or ``500 steps``; ``-``: its recipe's or its own."""
        return "-" if self.train_budget is None else budget_words(*self.train_budget)

    @property
    def is_reference(self) -> bool:
        return self.reference_name is not None

    @property
    def family(self) -> str:
        """The label of the unrefined row this one is (or is refined from)."""
        return self.base_label or self.label

    @property
    def pure_optimisation(self) -> bool:
        """``mean`` refined: refinement from constant maps, optimisation alone."""
        return self.baseline and self.refine_steps > 0 and self.family == REFERENCE

    @property
    def name(self) -> str:
        """The row label of the tables: baselines are marked (``mean`` refined as the
        pure-optimisation baseline); a reference row's label says its budget."""
        if self.pure_optimisation:
            return f"{self.label} ({PURE_OPTIMISATION})"
        return f"{self.label} (baseline)" if self.baseline else self.label

    @property
    def short(self) -> str:
        """The name where budgets and costs are compared, and in the plots: ``NAME (reference)``."""
        if not self.is_reference:
            return self.name
        refined = f" +refine {self.refine_steps}" if self.refine_steps else ""
        return f"{self.reference_name}{refined} (reference)"
