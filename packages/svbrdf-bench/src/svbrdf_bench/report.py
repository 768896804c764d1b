"""Benchmark reports, built from MLflow alone (so ``svbrdf-bench report PARENT`` rebuilds them).

Tables in the layout of the paper's Tables 1-4 (rows = models, then the untrained baselines
``mean`` and ``photo``; columns = the four maps and the renderings), one per metric, each figure
with its 95% bootstrap interval over test images; on a real test set (strips with the materials
the parent's ``eval/test_groups.json`` records) each figure is the mean over source materials of
the per-material means (a Des18 strip counts for both its materials), intervals and paired
comparisons resampling materials (:func:`svbrdf_train.data.materials.per_material`); whether each
trained model beats the constant-map baseline ``mean``, map by map (paired bootstrap of the RMSE difference), which the
headline repeats in words; the time table (training time on the budget clock and wall time,
throughput, latency, parameters, memory); and what each trained model's extra accuracy costs
against each other one, saying when the difference lies within noise.

Timings are medians with their interquartile range, ``19.3 [0.8]`` (:mod:`svbrdf_bench.timing`);
when the machine's load while a latency was measured makes it unreliable (a thread of the timing
waited for a CPU more than :data:`~svbrdf_bench.timing.CPU_WAIT_LIMIT` of the time), the report
says so in words at its top. The Pareto front of render RMSE against latency is noise-aware: a
model is dominated when a faster one's render RMSE is lower or within noise of its own (the
same 95% paired bootstrap as the other comparisons), so it is on the front only if it is faster
or better beyond noise (:meth:`Report.latency_front`).

Reference rows (model files trained elsewhere: ``--from-models``, ``--models pretrained``) stand in
every table under a label that gives their budget and says they are not equal-budget; where the
report speaks of budgets and costs (the header, the clock, the time table, what accuracy costs,
the plots) they are named ``NAME (reference)`` and a note says their training figures are what
their files record.

With ``--refine 0,N,...`` each row is followed by its refined rows, ``<row> +refine N`` (its maps
refined for N steps against each test photo); ``mean +refine N`` is named the pure-optimisation
baseline, and each refined model is held against it (not against the unrefined ``mean``): what
the network adds over optimisation alone at the same budget. A table and a plot
(``accuracy_vs_capture_time.png``) set accuracy against seconds per image. With ``--real-data``
too, the real-photo table holds the refined rows (with a note that re-rendering the photo is what
refinement optimises) and ``real_comparison.png`` shows their maps under their model's.

The runs are read as :mod:`svbrdf_bench.layout` describes them; this module never imports the
runner that writes them.
"""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from svbrdf_render.files import atomic_output, write_text

from .errors import BenchError
from .layout import (
    BASELINES_PARAM,
    BENCH_KIND,
    BUDGET_PREFIX,
    FIT_WALL_METRIC,
    GROUP_BY_PARAM,
    INPUT_RERENDER,
    KIND_TAG,
    LPIPS_TAG,
    MINUTES_PARAM,
    MODEL_SHA_TAG,
    MODEL_SOURCE_TAG,
    MODEL_TAG,
    PARENT_TAG,
    PER_SAMPLE,
    PRESET_PARAM,
    REAL_DATA_PARAM,
    REAL_PREFIX,
    REAL_RERENDER,
    REFINE_BACKEND_PARAM,
    REFINE_FLASH_PARAM,
    REFINE_PARAM,
    REFINED_FROM_TAG,
    SECONDS_PER_IMAGE,
    STEPS_METRIC,
    STEPS_WALL_METRIC,
    TEST_GROUPS,
    TEST_SET_PARAM,
    TRAINER_PREFIXES,
    is_baseline,
    read_per_sample,
    read_test_groups,
    reference_name,
    refine_steps,
    train_run_id,
)
from .timing import CPU_WAIT_LIMIT, LATENCY_METRIC, SPREAD_LIMIT, Load

__all__ = [
    "Report",
    "ModelEntry",
    "build_report",
    "write_report",
    "COLUMNS",
    "REFERENCE",
    "PURE_OPTIMISATION",
]

COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")
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
_SPREADS = {
    "time/latency_ms": ("time/latency_ms", "time/latency_iqr_ms"),
    "time/train_ms_per_step": ("time/train_ms_per_step_median", "time/train_ms_per_step_iqr"),
}
#: Figures a refined row shows from the row it refined (the same model, the same training).
_INHERITED = ("time/train_s", STEPS_WALL_METRIC, STEPS_METRIC, "time/train_samples_per_s",
              "time/train_ms_per_step", "time/train_ms_per_step_median", "time/train_ms_per_step_iqr",
              "memory/peak_rss_mb", "memory/peak_cuda_mb")  # fmt: skip


@dataclass
class ModelEntry:
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


@dataclass
class Report:
    parent_id: str
    preset: str
    test_set: str
    lpips_note: str
    minutes: str
    models: list[ModelEntry]
    real_data: str = "-"
    #: The baselines the benchmark was asked for ("-": none, --no-baselines; None: not recorded).
    baselines: str | None = None
    #: The refinement budgets, backend and flash (parent params); budgets "0": no refinement.
    refine: dict[str, str] = field(default_factory=dict)
    #: The source materials of each test sample, in order (parent artifact ``eval/test_groups.json``);
    #: None: each image its own (procedural test sets, older runs): figures are means over images.
    groups: list[tuple[str, ...]] | None = None
    #: The name of each test sample, in order (with :attr:`groups`).
    sample_names: list[str] = field(default_factory=list)
    #: How the samples were grouped: ``des18`` or ``file`` (with :attr:`groups`).
    group_by: str | None = None
    #: :meth:`latency_front`'s last answer, with the rows it was computed for.
    _front_cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- per material -------------------------------------------------------------------------

    @property
    def per_material_on(self) -> bool:
        return self.groups is not None

    @property
    def unit(self) -> str:
        """What the tables' means and bootstraps run over: ``materials`` or ``test images``."""
        return "materials" if self.per_material_on else "test images"

    def _per_material(self, e: ModelEntry, keys):
        from svbrdf_train.data.materials import per_material

        rows = []
        for i, g in enumerate(self.groups or []):
            rows.append((g, {k: float(e.per_sample[k][i]) for k in keys}))
        return per_material(rows)

    def values(self, e: ModelEntry, key: str) -> np.ndarray | None:
        """The values of per-sample figure ``key`` the tables average: per material (the mean of
        the strips showing it, materials sorted) on a grouped test set, else per image; figures on
        real photos (``real/``) are never grouped. None when the row lacks the figure."""
        v = e.per_sample.get(key)
        if v is None or len(v) == 0:
            return None
        if not self.per_material_on or key.startswith(REAL_PREFIX):
            return v
        if len(v) != len(self.groups):
            raise BenchError(
                f"{e.label}: {len(v)} values of {key} for the {len(self.groups)} test samples the parent "
                "run records; the runs do not belong together"
            )
        return np.asarray(self._per_material(e, [key]).values(key), dtype=np.float64)

    def averaging_note(self) -> str:
        """How many strips and materials the tables are over, and how they are averaged."""
        if not self.per_material_on:
            n = len(next(iter(self.models)).per_sample.get("rmse/render", ())) if self.models else 0
            return (
                f"tables over {n} test images, each its own material (mean over images; "
                "95% bootstrap intervals over images)"
            )
        materials = sorted({m for g in self.groups for m in g})
        how = (
            "a Des18 strip counts for both materials its name gives"
            if self.group_by == "des18"
            else "one material per file"
        )
        return (
            f"tables over {len(self.groups)} strips of {len(materials)} materials ({how}): each figure is "
            "the mean over materials of the mean over each material's strips, so every material weighs "
            "alike; bootstrap intervals and paired comparisons resample materials; per-strip figures "
            "are in results.json"
        )

    def per_strip_json(self) -> dict:
        """Per-strip figures of every row (``names``: the test samples, in order), and, on a grouped
        test set, each row's per-material means."""
        out: dict = {"names": list(self.sample_names), "groups": [list(g) for g in self.groups or []]}
        out["rows"] = {e.label: {k: v.tolist() for k, v in e.per_sample.items()} for e in self.models}
        if self.per_material_on:
            out["per_material"] = {}
            for e in self.models:
                keys = [k for k in e.per_sample if not k.startswith(REAL_PREFIX)]
                pm = self._per_material(e, keys)
                out["per_material"][e.label] = {"materials": pm.materials, "strips": pm.counts}
        return out

    # -- figures ----------------------------------------------------------------------------

    @property
    def trained(self) -> list[ModelEntry]:
        """Every row that is not an untrained baseline (reference rows included)."""
        return [e for e in self.models if not e.baseline]

    @property
    def competitors(self) -> list[ModelEntry]:
        """The models trained (or reused) at this benchmark's budget: no baselines, no reference rows,
        no refined rows."""
        return [e for e in self.trained if not e.is_reference and not e.refine_steps]

    @property
    def reference_rows(self) -> list[ModelEntry]:
        """Model files trained elsewhere (``--from-models``, ``--models pretrained``), unrefined."""
        return [e for e in self.models if e.is_reference and not e.refine_steps]

    @property
    def refined(self) -> list[ModelEntry]:
        """The refined rows (``--refine``), baselines' included."""
        return [e for e in self.models if e.refine_steps]

    def refine_note(self) -> str | None:
        """What the refined rows are, and which row is the pure-optimisation baseline."""
        if not self.refined:
            return None
        budgets = sorted({e.refine_steps for e in self.refined})
        how = ", ".join(
            f"{what} {self.refine[key]}"
            for key, what in ((REFINE_BACKEND_PARAM, "backend"), (REFINE_FLASH_PARAM, "flash"))
            if key in self.refine
        )
        pure = (
            f"; `{REFERENCE} +refine N` refines constant maps: the {PURE_OPTIMISATION}, optimisation alone, "
            "and each refined model is held against it at the same N (what the network adds over it)"
            if any(e.pure_optimisation for e in self.refined)
            else ""
        )
        return (
            f"refined rows (`+refine N`): each row's maps refined by svbrdf_render.refine_maps for N Adam "
            f"steps against each test photo (N = {', '.join(map(str, budgets))}"
            + (f"; {how}" if how else "")
            + f"), then scored alike{pure}; s/image: network forward plus refinement (flash finding "
            "included), one image at a time"
        )

    def budget_words(self) -> str:
        """The training budget in words; says that reference rows keep their own."""
        if self.reference_rows and self.competitors:
            return f"{self.minutes}; reference rows: their own budgets, not equal"
        return self.minutes

    def reference_note(self) -> str | None:
        """What the reference rows are: trained elsewhere, figures from their files, not competitors."""
        if not self.reference_rows:
            return None
        files = "; ".join(
            f"{e.short} = {e.budget.get('source', '?')} (SHA-256 {e.budget.get('sha256', '?')[:12]})"
            for e in self.reference_rows
        )
        return (
            "reference rows are model files trained elsewhere, scored on the same test images: their "
            "training time and steps are what each file records (its own budget and hardware), not "
            f"this benchmark's, so they are no equal-budget competitors: {files}"
        )

    def reference(self, steps: int = 0) -> ModelEntry | None:
        """The ``mean`` baseline's entry, if it was evaluated; ``steps`` > 0: ``mean`` refined for as
        many steps (the pure-optimisation baseline)."""
        return next(
            (e for e in self.models if e.baseline and e.family == REFERENCE and e.refine_steps == steps), None
        )

    def against_reference(self) -> list[dict]:
        """Per trained model and column: its RMSE minus ``mean``'s over the same images, and the verdict.

        ``verdict`` is ``"beats"`` when the whole 95% paired bootstrap interval lies below 0,
        ``"worse"`` when it lies above, ``"within noise"`` when it contains 0. A row refined for N
        steps is held against ``mean`` refined for N steps (the pure-optimisation baseline).
        """
        from .metrics import paired_difference

        if self.reference() is None:
            return []
        out = []
        for e in self.trained:
            ref = self.reference(e.refine_steps)
            if ref is None:
                continue
            for c in COLUMNS:
                a, b = e.per_sample.get(f"rmse/{c}"), ref.per_sample.get(f"rmse/{c}")
                if a is None or b is None:
                    continue
                if len(a) != len(b):
                    raise BenchError(f"{e.label} and {ref.label} were tested on different test sets")
                a, b = self.values(e, f"rmse/{c}"), self.values(ref, f"rmse/{c}")  # paired over materials
                d = paired_difference(a, b)
                verdict = "within noise" if d.within_noise else "beats" if d.mean < 0 else "worse"
                base = float(np.mean(b))
                out.append({"model": e.label, "versus": ref.label, "column": c, "rmse_difference": d.mean,
                            "low": d.low, "high": d.high, "verdict": verdict,
                            "relative": d.mean / base if base > 0 else math.nan})  # fmt: skip
        return out

    def not_beating(self) -> dict[str, list[dict]]:
        """Trained model -> the columns on which it does not beat ``mean`` (worse or within noise)."""
        out: dict[str, list[dict]] = {e.label: [] for e in self.trained}
        for row in self.against_reference():
            if row["verdict"] != "beats":
                out[row["model"]].append(row)
        return out

    def headline(self) -> list[str]:
        """What a reader must see first: per trained model, whether it beats the constant maps."""
        if self.reference() is None:
            if self.baselines in ("-", ""):
                return ["No baseline was evaluated (--no-baselines): nothing here says whether the models "
                        "beat constant maps derived from the photo."]  # fmt: skip
            return []
        synthetic = "procedural" in self.test_set
        lines = []
        failing = self.not_beating()
        for e in self.trained:
            label, rows, ref = e.label, failing[e.label], self.reference(e.refine_steps)
            if ref is None:
                continue
            if e.refine_steps:
                lines.append(self._refined_headline(e, ref, rows))
                continue
            if not rows:
                lines.append(f"{label} beats the constant-map baseline `{REFERENCE}` on every map and on "
                             "renderings (RMSE, 95% paired bootstrap).")  # fmt: skip
                continue
            cols = [r["column"] for r in rows]
            worse = [r["column"] for r in rows if r["verdict"] == "worse"]
            noise = [r["column"] for r in rows if r["verdict"] == "within noise"]
            why = "; ".join(
                part for part in (f"worse on {', '.join(worse)}" if worse else "",
                                  f"within noise on {', '.join(noise)}" if noise else "") if part
            )  # fmt: skip
            where = (
                "there that constant maps do not already give, even on synthetic test images"
                if synthetic
                else "that transfers there"
            )
            lines.append(
                f"{label} does NOT beat the constant-map baseline `{REFERENCE}` on {', '.join(cols)}: it has "
                f"learned nothing {where} ({why})."
            )
        return lines

    @staticmethod
    def _refined_headline(e: ModelEntry, ref: ModelEntry, rows: list[dict]) -> str:
        what = f"the {PURE_OPTIMISATION} `{ref.label}`"
        if not rows:
            return f"{e.label} beats {what} on every map and on renderings (RMSE, 95% paired bootstrap)."
        worse = [r["column"] for r in rows if r["verdict"] == "worse"]
        noise = [r["column"] for r in rows if r["verdict"] == "within noise"]
        parts = (
            f"worse on {', '.join(worse)}" if worse else "",
            f"within noise on {', '.join(noise)}" if noise else "",
        )
        why = "; ".join(part for part in parts if part)
        return (
            f"{e.label} does NOT beat {what} on {', '.join(r['column'] for r in rows)}: refining constant "
            f"maps for as many steps does as well there, the network adds nothing ({why})."
        )

    def clock_note(self) -> str:
        """Which clock budgeted the trained models' training time (reference rows: not this budget)."""
        trained = self.competitors
        if not trained:
            return "no model trained at this benchmark's budget" if self.trained else "no trained model"
        words = {
            e.label: CLOCK_WORDS.get(e.clock, f"{e.clock} clock") if e.clock else "wall clock (none recorded)"
            for e in trained
        }
        if len(set(words.values())) == 1:
            return f"training time budgeted and reported on the {next(iter(words.values()))}"
        return "training time budgeted and reported on " + "; ".join(
            f"{label}: the {w}" for label, w in words.items()
        )

    def init_notes(self) -> list[str]:
        """One line per fine-tuned model: where it started and the training time before."""
        return [
            f"{e.label} was fine-tuned from {e.init[0]} (fit --init), which had trained {e.init[1]:.0f} s "
            "on the same clock: its learning curve starts there, and its whole training time is that "
            "plus the time table's"
            for e in self.competitors
            if e.init is not None
        ]

    def interval(self, model: ModelEntry, metric: str, column: str) -> tuple[float, float, float] | None:
        from .metrics import bootstrap_ci

        values = self.values(model, f"{metric}/{column}")
        return None if values is None else bootstrap_ci(values)

    def metrics_present(self) -> list[tuple[str, str, str]]:
        return [m for m in METRICS if any(f"{m[0]}/render" in e.per_sample for e in self.models)]

    @property
    def costed(self) -> list[ModelEntry]:
        """The rows "what accuracy costs" pairs: trained and reference rows, unrefined (refined rows'
        cost is their seconds per image, in the refinement table)."""
        return [e for e in self.trained if not e.refine_steps]

    def costs(self) -> list[dict]:
        """Every ordered pair (A, B), A more accurate on renderings: what A's accuracy costs."""
        from .metrics import paired_difference

        out = []
        for a in self.costed:
            for b in self.costed:
                if a is b:
                    continue
                ra, rb = a.per_sample["rmse/render"], b.per_sample["rmse/render"]
                if len(ra) != len(rb):
                    raise BenchError(f"{a.label} and {b.label} were tested on different test sets")
                ra, rb = self.values(a, "rmse/render"), self.values(b, "rmse/render")
                if ra.mean() > rb.mean():
                    continue
                d = paired_difference(ra, rb)

                def ratio(key, a=a, b=b):
                    x, y = a.figures.get(key, math.nan), b.figures.get(key, math.nan)
                    return x / y if y and not math.isnan(x) and not math.isnan(y) else math.nan

                out.append(
                    {
                        "model": a.label,
                        "versus": b.label,
                        "reference": a.is_reference or b.is_reference,
                        "render_rmse_difference": d.mean,
                        "low": d.low,
                        "high": d.high,
                        "within_noise": bool(d.within_noise),
                        "train_time_per_step_ratio": ratio("time/train_ms_per_step"),
                        "latency_ratio": ratio("time/latency_ms"),
                        "params_ratio": ratio("model/params"),
                    }
                )
        return out

    # -- timings ------------------------------------------------------------------------------

    def _timed(self) -> list[ModelEntry]:
        """The rows with a latency, as the time table and the Pareto plot show them."""
        return [e for e in self.models if not math.isnan(e.figures.get("time/latency_ms", math.nan))]

    def latency_loads(self) -> dict[str, Load | None]:
        """Per row with a latency (by its short name): the load while it was measured (None: not
        recorded, a run from before the load was read)."""
        return {e.short: Load.from_metrics(e.figures, LATENCY_METRIC) for e in self._timed()}

    def timing_warning(self) -> str | None:
        """A warning in words when the load while a latency was measured makes it unreliable."""
        loads = {k: v for k, v in self.latency_loads().items() if v is not None and v.unreliable}
        if not loads:
            return None
        worst_name, worst = max(loads.items(), key=_worst_load)
        return (
            f"TIMINGS UNRELIABLE: the machine was busy while the latency of {', '.join(loads)} was measured "
            f"(worst, {worst_name}: {worst.words()}). A time measured while its thread waits for a CPU "
            f"more than {100 * CPU_WAIT_LIMIT:.0f}% of the time is inflated by more than "
            f"{100 * CPU_WAIT_LIMIT / (1 - CPU_WAIT_LIMIT):.0f}%, more than the spread expected on an idle "
            f"machine (an IQR under {100 * SPREAD_LIMIT:.0f}% of the median), "
            "and by an amount that depends on what else ran at that moment: these latencies, their ratios "
            "and the Pareto front cannot be compared. Rerun on an idle machine (`svbrdf-bench run "
            "--from-runs ...` times the fits again without retraining them)."
        )

    def timing_notes(self) -> list[str]:
        """How the times were measured, the load while they were, and which spreads are wide."""
        timed = self._timed()
        if not timed:
            return []
        runs = sorted({int(e.figures[f"{LATENCY_METRIC}_runs"]) for e in timed
                       if f"{LATENCY_METRIC}_runs" in e.figures})  # fmt: skip
        how = f"{'/'.join(map(str, runs))} timed runs" if runs else "timed runs"
        lines = [
            f"latency: median [interquartile range] of {how} on one 256x256 image, after 3 warm-up runs; "
            "train ms/step: median [IQR] over the fit's logging windows (budget clock), where logged"
        ]
        loads = self.latency_loads()
        read = {k: v for k, v in loads.items() if v is not None}
        if not read:
            lines.append("the machine's load while timing was not recorded (an older run): nothing checks "
                         "these latencies")  # fmt: skip
        elif self.timing_warning() is None:
            worst_name, worst = max(read.items(), key=_worst_load)
            verdict = (
                f"under the {100 * CPU_WAIT_LIMIT:.0f}% limit of time waiting for a CPU"
                if worst.cpu_wait is not None
                else "not above one runnable task per CPU"
                if worst.unreliable is False
                else "not measurable on this system"
            )
            lines.append(f"load while timing (worst, {worst_name}): {worst.words()}; {verdict}")
        wide = []
        for e in timed:
            median, iqr = e.figures["time/latency_ms"], e.figures.get("time/latency_iqr_ms", math.nan)
            if median > 0 and iqr / median > SPREAD_LIMIT:
                wide.append(f"{e.short} ({100 * iqr / median:.0f}%)")
        if wide:
            lines.append(
                f"wide spread (IQR over {100 * SPREAD_LIMIT:.0f}% of the median latency): {', '.join(wide)}"
            )
        return lines

    def latency_front(self) -> dict:
        """The Pareto front of render RMSE against latency, with noise.

        Returns ``points`` (``{name: (latency ms, render RMSE, low, high)}``: the rows with both),
        ``within_noise`` (the pairs of them whose 95% paired bootstrap interval of the render RMSE
        difference contains 0, as in "what accuracy costs"), ``front`` (names, by latency) and
        ``dominated`` (``{name: the fastest row that dominates it}``, see
        :func:`svbrdf_bench.plots.dominated_by`).
        """
        from .metrics import paired_difference
        from .plots import dominated_by

        key = tuple((e.run_id, e.figures.get("time/latency_ms")) for e in self.models)
        if self._front_cache.get("key") == key:  # the report text and the plot ask alike
            return self._front_cache["front"]
        rows, points = {}, {}
        for e in self._timed():
            ci = self.interval(e, "rmse", "render")
            if ci is not None:
                name = e.short if e.is_reference else e.label
                rows[name], points[name] = e, (e.figures["time/latency_ms"], *ci)
        if not points:
            return {"points": {}, "within_noise": [], "front": [], "dominated": {}}
        names = list(points)
        ties = []
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                va, vb = self.values(rows[a], "rmse/render"), self.values(rows[b], "rmse/render")
                if len(va) == len(vb) and paired_difference(va, vb).within_noise:
                    ties.append((a, b))
        by = dominated_by(points, within_noise=ties)
        front = sorted((n for n in names if by[n] is None), key=lambda n: (points[n][0], points[n][1], n))
        out = {
            "points": points,
            "within_noise": ties,
            "front": front,
            "dominated": {n: b for n, b in by.items() if b is not None},
        }
        self._front_cache.update(key=key, front=out)
        return out

    def _front_lines(self) -> list[str]:
        """The front in words: who is on it, and why each other row is not."""
        pf = self.latency_front()
        if len(pf["points"]) < 2:
            return []
        ties = {frozenset(p) for p in pf["within_noise"]}
        why = []
        for name, by in pf["dominated"].items():
            (xa, ya), (xb, yb) = pf["points"][name][:2], pf["points"][by][:2]
            speed = "faster" if xb < xa else "as fast"
            accuracy = (
                "within noise of it in render RMSE" if frozenset((name, by)) in ties
                else "more accurate beyond noise" if yb < ya else "as accurate"
            )  # fmt: skip
            why.append(f"{name} ({by} is {speed} and {accuracy})")
        lines = [
            "Latency against render RMSE: on the Pareto front (faster than, or more accurate beyond noise "
            f"than, every row at least as fast; 95% paired bootstrap): {', '.join(pf['front'])}"
            + (f"; dominated: {'; '.join(why)}" if why else "")
            + "."
        ]
        if self.timing_warning():
            lines.append("The latencies were measured on a busy machine (see the warning above), and so was "
                         "this front.")  # fmt: skip
        return lines

    # -- text -------------------------------------------------------------------------------

    def _accuracy_table(self, metric: str, title: str, sense: str, markdown: bool) -> list[str]:
        head = ["model", *COLUMNS]
        rows = []
        for e in self.models:
            cells = [e.name]
            for c in COLUMNS:
                ci = self.interval(e, metric, c)
                cells.append("-" if ci is None else f"{ci[0]:.4f} [{ci[1]:.4f}, {ci[2]:.4f}]")
            rows.append(cells)
        over = (
            "mean over materials; 95% bootstrap interval over materials"
            if self.per_material_on
            else "95% bootstrap interval over test images"
        )
        return _table(f"{title} ({sense}; {over})", head, rows, markdown)

    def _against_table(self, markdown: bool) -> list[str]:
        rows_by_model: dict[str, dict[str, str]] = {}
        for r in self.against_reference():
            rel = "" if math.isnan(r["relative"]) else f" ({100 * r['relative']:+.0f}%)"
            cell = f"{r['rmse_difference']:+.4f}{rel} [{r['low']:+.4f}, {r['high']:+.4f}] {r['verdict']}"
            rows_by_model.setdefault(r["model"], {})[r["column"]] = cell
        if not rows_by_model:
            return []
        rows = [[m, *(cells.get(c, "-") for c in COLUMNS)] for m, cells in rows_by_model.items()]
        refined = (
            f"; a row refined for N steps against `{REFERENCE} +refine N`, the {PURE_OPTIMISATION}"
            if any(e.refine_steps for e in self.trained)
            else ""
        )
        title = (
            f"Against the {REFERENCE} baseline (RMSE of the model minus RMSE of `{REFERENCE}` on the same "
            f"{'materials' if self.per_material_on else 'images'}, in % of `{REFERENCE}`'s RMSE, 95% paired "
            "bootstrap interval; beats: the whole "
            f"interval below 0{refined})"
        )
        return _table(title, ["model", *COLUMNS], rows, markdown)

    def _time_table(self, markdown: bool) -> list[str]:
        cols = [c for c in TIME_COLUMNS if any(c[0] in e.figures for e in self.models)]
        rows = []
        for e in self.models:
            cells = [e.short]
            for key, _, fmt in cols:
                v = e.figures.get(key, math.nan)
                if key == "model/params":
                    v = v / 1e6
                median, iqr = (e.figures.get(k, math.nan) for k in _SPREADS.get(key, (key, "")))
                if not (math.isnan(median) or math.isnan(iqr)):  # median [IQR]
                    cells.append(f"{fmt.format(median)} [{fmt.format(iqr)}]")
                    continue
                cells.append("-" if v is None or math.isnan(v) else fmt.format(v))
            rows.append(cells)
        table = _table("Time and memory", ["model", *(c[1] for c in cols)], rows, markdown)
        if self.reference_rows:
            table += [
                "",
                "Rows marked (reference): training time and steps as their model files record them, "
                "on their own budget and hardware; not this benchmark's budget, and not comparable "
                "with it.",
            ]
        return table

    def _refine_table(self, markdown: bool) -> list[str]:
        """Accuracy against capture time: every row with refinement on, at every budget."""
        if not self.refined:
            return []
        rows = []
        for e in self.models:
            cells = [e.name, str(e.refine_steps)]
            seconds = e.figures.get(SECONDS_PER_IMAGE, math.nan)
            cells.append("-" if math.isnan(seconds) else f"{seconds:.3g}")
            for key in (INPUT_RERENDER, "rmse/render", "rmse/diffuse"):
                ci = self.interval(e, *key.split("/", 1))
                cells.append("-" if ci is None else f"{ci[0]:.4f} [{ci[1]:.4f}, {ci[2]:.4f}]")
            rows.append(cells)
        head = ["model", "refine steps", "s/image (net + refine)", "photo re-render RMSE", "render RMSE",
                "diffuse RMSE"]  # fmt: skip
        title = (
            "Refinement: accuracy against capture time (photo re-render: the maps under the refinement's "
            "flash against the test photo, what refinement optimises; render: the 6 evaluation views "
            "against the true maps'; 95% bootstrap intervals)"
        )
        return _table(title, head, rows, markdown)

    def _real_table(self, markdown: bool) -> list[str]:
        """Real photos have no ground truth: the re-rendering under the fitted flash is the figure."""
        from .metrics import bootstrap_ci

        rows = []
        for e in self.models:
            values = e.per_sample.get(REAL_RERENDER)
            if values is None or len(values) == 0:
                continue
            mean, low, high = bootstrap_ci(values)
            rows.append(
                [e.name, str(len(values)), f"{np.median(values):.4f}", f"{mean:.4f} [{low:.4f}, {high:.4f}]"]
            )
        if not rows:
            return []
        head = ["model", "photos", "median re-render RMSE", "mean [95%]"]
        table = _table(
            f"Real photos ({self.real_data}): maps re-rendered under the fitted flash", head, rows, markdown
        )
        refined = any(e.refine_steps and len(e.per_sample.get(REAL_RERENDER, ())) for e in self.models)
        return [*table, "", REAL_CAVEAT, *(["", REAL_REFINED_CAVEAT] if refined else [])]

    def _cost_lines(self, markdown: bool) -> list[str]:
        rows, notes = [], []
        costs = self.costs()
        short = {e.label: e.short for e in self.costed}
        for c in costs:
            noise = "within noise" if c["within_noise"] else "beyond noise"
            a, b = short[c["model"]], short[c["versus"]]
            rows.append(
                [
                    f"{a} vs {b}",
                    f"{c['render_rmse_difference']:+.4f} [{c['low']:+.4f}, {c['high']:+.4f}]",
                    noise,
                    _ratio(c["train_time_per_step_ratio"]),
                    _ratio(c["latency_ratio"]),
                    _ratio(c["params_ratio"]),
                ]
            )
            if c["reference"]:
                difference = (
                    "a render RMSE difference within the noise of this test set"
                    if c["within_noise"]
                    else f"{-c['render_rmse_difference']:.4f} render RMSE better"
                )
                notes.append(
                    f"{a} against {b}: {difference}, at {_ratio(c['latency_ratio'])} the latency and "
                    f"{_ratio(c['params_ratio'])} the parameters; a reference row trained on its own "
                    "budget, so this is no comparison at equal training cost."
                )
            elif c["within_noise"]:
                notes.append(
                    f"{c['model']} and {c['versus']}: the render RMSE difference lies within the noise of "
                    f"this test set (its interval contains 0); the extra cost buys no measurable accuracy."
                )
            else:
                notes.append(
                    f"{c['model']} renders {-c['render_rmse_difference']:.4f} RMSE better than {c['versus']} "
                    f"for {_ratio(c['train_time_per_step_ratio'])} the training time per step and "
                    f"{_ratio(c['latency_ratio'])} the latency."
                )
        failing = {m for m, rows in self.not_beating().items() if any(r["column"] == "render" for r in rows)}
        pairs = dict.fromkeys(x for c in costs for x in (c["model"], c["versus"]))
        compared = [short[m] for m in pairs if m in failing]
        if compared:
            notes.append(
                f"{', '.join(compared)} {'does' if len(compared) == 1 else 'do'} not beat the constant-map "
                f"baseline `{REFERENCE}` on renderings: what these pairs trade against time is accuracy "
                "a constant map already has."
            )
        head = ["pair", "render RMSE difference [95%]", "noise", "train time/step", "latency", "params"]
        title = "What accuracy costs (trained models" + ("; reference rows: not equal-budget)" if any(
            c["reference"] for c in costs) else ")")  # fmt: skip
        return [*_table(title, head, rows, markdown), *notes]

    def _tables(self, markdown: bool) -> list[str]:
        lines = []
        for metric, title, sense in self.metrics_present():
            lines += [*self._accuracy_table(metric, title, sense, markdown), ""]
        against = self._against_table(markdown)
        lines += [*against, ""] if against else []
        real = self._real_table(markdown)
        lines += [*real, ""] if real else []
        refine = self._refine_table(markdown)
        lines += [*refine, ""] if refine else []
        lines += [*self._time_table(markdown), ""]
        notes = self.timing_notes()
        lines += [*(f"- {n}" if markdown else n for n in notes), ""] if notes else []
        if len(self.costed) > 1:
            lines += [*self._cost_lines(markdown), ""]
        front = self._front_lines()
        lines += [*front, ""] if front else []
        return lines

    def terminal(self) -> str:
        note, refine = self.reference_note(), self.refine_note()
        lines = [
            f"svbrdf-bench: {', '.join(e.name for e in self.models)} ({self.preset}; {self.budget_words()})",
            *self.headline(),
            f"test set: {self.test_set}; {self.lpips_note}",
            self.averaging_note(),
            self.clock_note(),
            *([warning] if (warning := self.timing_warning()) else []),
            *self.init_notes(),
            *([note] if note else []),
            *([refine] if refine else []),
            "",
            *self._tables(False),
        ]
        return "\n".join(lines).rstrip("\n")

    def markdown(self, files: dict[str, str]) -> str:
        lines = [
            f"# Benchmark: {', '.join(e.name for e in self.models)}",
            "",
            *(line for h in self.headline() for line in (f"**{h}**", "")),
            *(line for w in [self.timing_warning()] if w for line in (f"**{w}**", "")),
            f"- preset: {self.preset} ({self.budget_words()})",
            f"- {self.clock_note()}",
            *(f"- {line}" for line in self.init_notes()),
            *(f"- {line}" for line in [self.reference_note()] if line),
            *(f"- {line}" for line in [self.refine_note()] if line),
            f"- test set: {self.test_set}",
            f"- {self.averaging_note()}",
            f"- {self.lpips_note}",
            f"- MLflow parent run: `{self.parent_id}`; rebuild with `svbrdf-bench report {self.parent_id}`",
            "",
        ]
        lines += self._tables(True)
        for name, caption in (
            ("learning_curves", "Validation render RMSE against training time"),  # dashed: real materials
            ("pareto", "Inference latency against render RMSE"),
            ("capture_time", "Render and diffuse RMSE against seconds per image (network + refinement)"),
            ("comparison", "Input, true maps and each model's maps, with flash re-renderings"),
            ("real_comparison", "Real photos: each model's maps and their re-rendering under the fitted "
             "flash, each refined version under its model's (re-rendering the photo's own view is what "
             "refinement optimises)"),
        ):
            if name in files:
                lines += [f"## {caption}", "", f"![{caption}]({files[name]})", ""]
        return "\n".join(lines)

    def records(self) -> list[dict]:
        out = []
        for e in self.models:
            rec = {"model": e.label, "baseline": e.baseline, "reference": e.is_reference, "run_id": e.run_id}
            if self.refined:
                rec |= {"refine_steps": e.refine_steps, "refined_from": e.base_label or "-",
                        "pure_optimisation": e.pure_optimisation}  # fmt: skip
            rec["train_run_id"] = "-" if e.baseline or e.is_reference else e.train_run_id
            if e.is_reference:  # trained elsewhere: its file, and the budget the file records
                rec["clock"] = "its own (not this benchmark's budget)"
                rec["reference_name"] = e.reference_name
                rec |= {f"reference_{k}": v for k, v in e.budget.items()}
            elif not e.baseline:
                rec["clock"] = e.clock or "wall (not recorded)"
            for metric, _, _ in self.metrics_present():
                for c in COLUMNS:
                    ci = self.interval(e, metric, c)
                    if ci is not None:
                        rec[f"{metric}_{c}"], rec[f"{metric}_{c}_low"], rec[f"{metric}_{c}_high"] = ci
            for key, _, _ in TIME_COLUMNS:
                if key in e.figures:
                    rec[key.replace("/", "_")] = e.figures[key]
            for key in sorted(e.figures):  # spreads and the load while timing
                if key.startswith((f"{LATENCY_METRIC}_", "time/train_ms_per_step_")) and key not in rec:
                    rec[key.replace("/", "_")] = e.figures[key]
            load = Load.from_metrics(e.figures, LATENCY_METRIC)
            if load is not None:
                rec["time_latency_unreliable"] = load.unreliable
            real = e.per_sample.get(REAL_RERENDER)
            if real is not None and len(real):
                rec["real_rerender_rmse_median"] = float(np.median(real))
            ci = self.interval(e, *INPUT_RERENDER.split("/", 1))
            if ci is not None:
                (
                    rec["photo_rerender_rmse"],
                    rec["photo_rerender_rmse_low"],
                    rec["photo_rerender_rmse_high"],
                ) = ci
            out.append(rec)
        return out


REAL_CAVEAT = (
    "Re-rendering RMSE measures consistency with the photo, not correctness: copying the photo into the "
    "diffuse map (the `photo` baseline) scores well without recovering any material."
)

#: Under the real-photo table when it holds refined rows (``--real-data`` with ``--refine``).
REAL_REFINED_CAVEAT = (
    "Refined rows (`+refine N`) had their maps of each real photo optimised to re-render that very "
    "photo: the re-rendering of the photo's own view is what refinement optimises, so their low "
    "re-render RMSE here holds by construction and is no evidence of accuracy (accuracy is measured "
    "on the test set only, against true maps)."
)


def _worst_load(item: tuple[str, Load]) -> tuple[float, float]:
    """Sort key of ``(row, load)``: the longest wait for a CPU, then the load average."""
    return (item[1].cpu_wait or 0.0, item[1].load_average or 0.0)


def _ratio(x: float) -> str:
    return "-" if x is None or math.isnan(x) else f"{x:.2f}x"


def _table(title: str, head: list[str], rows: list[list[str]], markdown: bool) -> list[str]:
    if markdown:
        return [
            f"## {title}",
            "",
            "| " + " | ".join(head) + " |",
            "| " + " | ".join("---" for _ in head) + " |",
            *("| " + " | ".join(r) + " |" for r in rows),
        ]
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return [title, fmt.format(*head), fmt.format(*("-" * w for w in widths)), *(fmt.format(*r) for r in rows)]


# -- from MLflow --------------------------------------------------------------------------------


def _curve(
    client, run_id: str, key: str = "val/rmse/render", offset: float = 0.0
) -> tuple[list[float], list[float]]:
    """``(training seconds, metric)`` at the validation steps of a fit (``key``: which figure);
    ``offset``: training time before the fit (a fine-tuned fit's starting weights)."""
    rmse = {m.step: m.value for m in client.get_metric_history(run_id, key)}
    seconds = {m.step: m.value for m in client.get_metric_history(run_id, "val/train_seconds")}
    steps = sorted(set(rmse) & set(seconds))
    return [offset + seconds[s] for s in steps], [rmse[s] for s in steps]


def build_report(parent_id: str) -> Report:
    """Everything the report shows, read back from the parent run and its children."""
    from mlflow import MlflowClient

    from svbrdf_train.clock import CLOCK_TAG

    client = MlflowClient()
    try:
        parent = client.get_run(parent_id)
    except Exception as e:  # MlflowException for an unknown id
        raise BenchError(f"no MLflow run {parent_id} in {client.tracking_uri} ({type(e).__name__})") from None
    if parent.data.tags.get(KIND_TAG) != BENCH_KIND:
        raise BenchError(f"run {parent_id} is not the parent run of an svbrdf-bench run")
    children = client.search_runs(
        [parent.info.experiment_id], filter_string=f"tags.`{PARENT_TAG}` = '{parent_id}'"
    )
    models = []
    with tempfile.TemporaryDirectory() as tmp:
        for child in sorted(children, key=lambda r: r.info.start_time):
            label = child.data.tags.get(MODEL_TAG)
            if label is None:
                continue  # trained but never evaluated (an interrupted benchmark)
            local = client.download_artifacts(child.info.run_id, PER_SAMPLE, tmp)
            per_sample = read_per_sample(Path(local).read_text())
            train_run = train_run_id(child.info.run_id, child.data.tags)
            metrics = child.data.metrics
            figures = {k: v for k, v in metrics.items() if not k.startswith(TRAINER_PREFIXES)}
            row = (label, child.info.run_id, train_run, per_sample, figures)  # what every entry has
            steps = refine_steps(child.data.tags)
            if steps:  # a row refined for `steps`: linked to the row it refined below
                models.append(ModelEntry(*row, baseline=is_baseline(child.data.tags),
                                         reference_name=reference_name(child.data.tags), refine_steps=steps,
                                         refined_from=child.data.tags.get(REFINED_FROM_TAG)))  # fmt: skip
                continue
            if is_baseline(child.data.tags):
                models.append(ModelEntry(*row, baseline=True))
                continue
            figures[STEPS_METRIC] = metrics.get(STEPS_METRIC, math.nan)
            short = reference_name(child.data.tags)
            if short is not None:  # a model file trained elsewhere: no fit, no learning curve here
                tags, params = child.data.tags, child.data.params
                budget = {"source": tags.get(MODEL_SOURCE_TAG, "?"), "sha256": tags.get(MODEL_SHA_TAG, "?")}
                budget |= {
                    k[len(BUDGET_PREFIX) :]: v for k, v in params.items() if k.startswith(BUDGET_PREFIX)
                }
                models.append(ModelEntry(*row, reference_name=short, budget=budget))
                continue
            if STEPS_WALL_METRIC not in figures and FIT_WALL_METRIC in metrics:
                figures[STEPS_WALL_METRIC] = metrics[FIT_WALL_METRIC]
            tags = child.data.tags if train_run == child.info.run_id else client.get_run(train_run).data.tags
            before = float(tags.get("svbrdf.init_train_seconds", 0.0))
            init = (tags["svbrdf.init"], before) if "svbrdf.init" in tags else None
            models.append(
                ModelEntry(
                    *row,
                    _curve(client, train_run, offset=before),
                    _curve(client, train_run, "val_real/rmse/render", offset=before),
                    clock=tags.get(CLOCK_TAG),
                    init=init,
                )
            )
    if not models:
        raise BenchError(f"run {parent_id} has no evaluated models yet")
    models = _link_refined(models)
    params = parent.data.params
    grouping: dict = {}
    if params.get(GROUP_BY_PARAM) in ("des18", "file"):
        with tempfile.TemporaryDirectory() as tmp:
            try:
                local = client.download_artifacts(parent_id, TEST_GROUPS, tmp)
            except Exception:  # recorded as grouped but the artifact is gone: per image, as before
                local = None
            if local is not None:
                group_by, names, groups = read_test_groups(Path(local).read_text())
                grouping = {"group_by": group_by, "sample_names": names, "groups": groups}
    minutes = params.get(MINUTES_PARAM, "?")
    return Report(
        parent_id=parent_id,
        preset=params.get(PRESET_PARAM, "?"),
        test_set=params.get(TEST_SET_PARAM, "?"),
        lpips_note=parent.data.tags.get(LPIPS_TAG, ""),
        minutes=f"{minutes} min of training per model" if minutes[:1].isdigit() else minutes,
        models=models,
        real_data=params.get(REAL_DATA_PARAM, "-"),
        baselines=params.get(BASELINES_PARAM),
        refine={
            k: params[k] for k in (REFINE_PARAM, REFINE_BACKEND_PARAM, REFINE_FLASH_PARAM) if k in params
        },
        **grouping,
    )


def _link_refined(models: list[ModelEntry]) -> list[ModelEntry]:
    """Each refined row after the row it refined (by budget), with that row's label, training run,
    clock, budget and training figures (the same model); a refined row whose row is missing last."""
    by_run = {e.run_id: e for e in models if not e.refine_steps}
    children: dict[str, list[ModelEntry]] = {}
    orphans = []
    for e in models:
        if not e.refine_steps:
            continue
        base = by_run.get(e.refined_from or "")
        if base is None:
            orphans.append(e)
            continue
        e.base_label, e.train_run_id, e.clock, e.budget = (
            base.label,
            base.train_run_id,
            base.clock,
            base.budget,
        )
        e.figures = {k: base.figures[k] for k in _INHERITED if k in base.figures} | e.figures
        children.setdefault(base.run_id, []).append(e)
    out = []
    for e in models:
        if not e.refine_steps:
            out += [e, *sorted(children.get(e.run_id, []), key=lambda r: r.refine_steps)]
    return out + orphans


def csv_text(rows: list[dict], columns: list[str] | None = None) -> str:
    """Rows as CSV text (columns: every key met, in order, unless given; None as empty)."""
    keys = columns or list(dict.fromkeys(k for r in rows for k in r))
    buffer = io.StringIO(newline="")
    w = csv.DictWriter(buffer, fieldnames=keys, extrasaction="ignore")
    w.writeheader()
    w.writerows({k: "" if r.get(k) is None else r[k] for k in keys} for r in rows)
    return buffer.getvalue()


def _capture_series(report: Report) -> tuple[dict[str, list], set[str]]:
    """``{row: [(seconds per image, steps, {column: (mean, low, high)})]}`` through its budgets,
    for :func:`~svbrdf_bench.plots.accuracy_vs_capture_time`, and the names of the baselines'
    lines (``mean``'s is named the pure-optimisation baseline); empty without refined rows."""
    if not report.refined:
        return {}, set()
    series: dict[str, list] = {}
    baselines = set()
    for e in report.models:
        seconds = e.figures.get(SECONDS_PER_IMAGE, math.nan)
        cis = {c: report.interval(e, "rmse", c) for c in ("render", "diffuse")}
        if math.isnan(seconds) or any(ci is None for ci in cis.values()):
            continue
        base = next((m for m in report.models if m.label == e.family and not m.refine_steps), e)
        name = (
            f"{base.label} ({PURE_OPTIMISATION} when refined)"
            if base.label == REFERENCE and e.baseline
            else base.short
        )
        if e.baseline:
            baselines.add(name)
        series.setdefault(name, []).append((seconds, e.refine_steps, cis))
    return series, baselines


def write_report(
    report: Report, out: str | Path, *, grid: Path | None = None, real_grid: Path | None = None
) -> list[Path]:
    """``report.md``, ``results.csv``, ``results.json``, ``costs.csv``, the plots and the grid;
    ``real_grid``: the real-photo sheet (``--real-data`` with ``--refine``), as ``real_comparison.png``."""
    from .plots import accuracy_vs_capture_time, learning_curves, pareto

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}
    written: list[Path] = []
    curves = {e.label: e.curve for e in report.models if e.curve[0]}
    real_curves = {e.label: e.curve_real for e in report.models if e.curve_real[0]}
    if curves or real_curves:
        written.append(
            learning_curves(
                curves,
                out / "learning_curves.png",
                real=real_curves,
                xlabel="training time, budget clock (s)",
            )
        )
        files["learning_curves"] = "learning_curves.png"
    front = report.latency_front()
    if front["points"]:
        written.append(pareto(front["points"], out / "pareto.png", within_noise=front["within_noise"]))
        files["pareto"] = "pareto.png"
    series, baselines = _capture_series(report)
    if series:
        written.append(
            accuracy_vs_capture_time(series, out / "accuracy_vs_capture_time.png", baselines=baselines)
        )
        files["capture_time"] = "accuracy_vs_capture_time.png"
    if grid is not None:
        target = out / "comparison.png"
        if Path(grid) != target:
            with atomic_output(target) as tmp:
                shutil.copyfile(grid, tmp)
        written.append(target)
        files["comparison"] = "comparison.png"
    if real_grid is not None:
        target = out / "real_comparison.png"
        if Path(real_grid) != target:
            with atomic_output(target) as tmp:
                shutil.copyfile(real_grid, tmp)
        written.append(target)
        files["real_comparison"] = "real_comparison.png"
    records = report.records()
    costs = report.costs() if len(report.costed) > 1 else []
    against = report.against_reference()
    write_text(
        out / "results.json",
        json.dumps(
            {
                "parent_run": report.parent_id,
                "preset": report.preset,
                "test_set": report.test_set,
                "averaged_over": report.unit,
                "averaging": report.averaging_note(),
                "headline": report.headline(),
                "budget_clock": report.clock_note(),
                "models": records,
                "against_mean": against,
                "costs": costs,
                "timing_warning": report.timing_warning(),
                "timing_notes": report.timing_notes(),
                "latency_front": {"front": front["front"], "dominated": front["dominated"],
                                  "within_noise": [list(p) for p in front["within_noise"]]},  # fmt: skip
                "per_strip": report.per_strip_json(),
            },
            indent=2,
        )  # fmt: skip
    )
    written.append(out / "results.json")
    for name, rows in (("results.csv", records), ("costs.csv", costs), ("against_mean.csv", against)):
        if rows:
            write_text(out / name, csv_text(rows))
            written.append(out / name)
    write_text(out / "report.md", report.markdown(files))
    written.append(out / "report.md")
    return written
