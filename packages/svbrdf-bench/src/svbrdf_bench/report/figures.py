"""The figures of a benchmark report, apart from how they are shown: :class:`Report` holds the rows
(:class:`~svbrdf_bench.report.rows.ModelEntry`) and computes every number the tables, the words
and the files show: the values averaged per material or per image, their 95% bootstrap
intervals, each trained row against ``mean`` (the verdict: ``beats``, ``worse``, ``within
noise``), what one model's accuracy costs against another, the noise-aware Pareto front of
render RMSE against latency, and one flat record per row (results.csv, results.json).

Figures on a grouped test set (``groups``) are per material: the mean of the strips showing it,
a Des18 strip counting for both its materials, so bootstraps and paired comparisons resample
materials; otherwise per test image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import BenchError
from ..layout import INPUT_RERENDER, REAL_PREFIX, REAL_RERENDER
from ..inference import CUDA_MEMORY_PREFIX, FLOPS_METRIC
from ..published import Published
from ..timing import LATENCY_METRIC, Load
from .rows import COLUMNS, METRICS, REFERENCE, TIME_COLUMNS, ModelEntry

__all__ = ["Report"]

#: Figures a row's record carries beyond the time columns: the spreads and the load while timing,
#: the latency grid, FLOPs and inference memory (:mod:`svbrdf_bench.inference`).
_RECORDED = (f"{LATENCY_METRIC}_", "time/train_ms_per_step_", FLOPS_METRIC, CUDA_MEMORY_PREFIX)


@dataclass
class Report:
    """A benchmark's rows and what the parent run records of it (preset, test set, budgets, how the
    test samples group into materials), with every figure computed from them."""

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
    #: Wall seconds of each phase of the benchmark, in order (parent metrics ``phase/*``; empty in
    #: older runs): ``[(name, seconds)]``.
    phases: list[tuple[str, float]] = field(default_factory=list)
    #: The training budgets a fit never reached (parent artifact ``eval/missed_budgets.json``):
    #: ``[{model, seed, budget, why}]`` (:mod:`~svbrdf_bench.report.seeds`).
    missed_budgets: list[dict] = field(default_factory=list)
    #: Published numbers set beside the rows (``--published``; the parent artifact
    #: ``eval/published.yaml``), never rows of their own: :mod:`~svbrdf_bench.report.published`.
    published: Published | None = None
    #: The side in px the test images were scored at (parent param ``test_resolution``); None: not recorded.
    resolution: int | None = None
    #: :meth:`latency_front`'s last answer, with the rows it was computed for.
    _front_cache: dict = field(default_factory=dict, repr=False, compare=False)
    #: :func:`svbrdf_bench.report.verdicts.family`'s last answer, with the rows it was computed for.
    _family_cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- per material -------------------------------------------------------------------------

    @property
    def per_material_on(self) -> bool:
        return self.groups is not None

    @property
    def unit(self) -> str:
        """What the tables' means and bootstraps run over: ``materials`` or ``test images``."""
        return "materials" if self.per_material_on else "test images"

    def _per_material(self, e: ModelEntry, keys):
        from svbrdf_train import per_material

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
        ``p_value``: the bootstrap's two-sided p (:func:`svbrdf_bench.metrics.bootstrap_p_value`),
        which :mod:`~svbrdf_bench.report.verdicts` corrects for the report's number of verdicts.
        """
        from ..metrics import paired_difference

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
                            "low": d.low, "high": d.high, "verdict": verdict, "p_value": d.p_value,
                            "relative": d.mean / base if base > 0 else math.nan})  # fmt: skip
        return out

    def not_beating(self) -> dict[str, list[dict]]:
        """Trained model -> the columns on which it does not beat ``mean`` (worse or within noise)."""
        out: dict[str, list[dict]] = {e.label: [] for e in self.trained}
        for row in self.against_reference():
            if row["verdict"] != "beats":
                out[row["model"]].append(row)
        return out

    def interval(self, model: ModelEntry, metric: str, column: str) -> tuple[float, float, float] | None:
        from ..metrics import bootstrap_ci

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
        """Every ordered pair (A, B), A more accurate on renderings: what A's accuracy costs. When a
        model has several seeds or budgets here (``--seeds``, ``--minutes 2,8,32``), rows are paired
        only with the rows of the same seed and budget: one checkpoint against another seed's or
        budget's says nothing the section "Across seeds and budgets" does not, and would swell the
        Holm family."""
        from ..metrics import paired_difference

        methods = [e.method for e in self.costed if e.method]
        matched = len(methods) != len(set(methods))  # a model has several seeds or budgets here
        out = []
        for a in self.costed:
            for b in self.costed:
                apart = a.method and b.method and (a.seed, a.train_budget) != (b.seed, b.train_budget)
                if a is b or (matched and apart):
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
                        "p_value": d.p_value,
                        "train_time_per_step_ratio": ratio("time/train_ms_per_step"),
                        "latency_ratio": ratio("time/latency_ms"),
                        "params_ratio": ratio("model/params"),
                    }
                )
        return out

    # -- timings ------------------------------------------------------------------------------

    def timed(self) -> list[ModelEntry]:
        """The rows with a latency, as the time table and the Pareto plot show them."""
        return [e for e in self.models if not math.isnan(e.figures.get("time/latency_ms", math.nan))]

    def latency_loads(self) -> dict[str, Load | None]:
        """Per row with a latency (by its short name): the load while it was measured (None: not
        recorded, a run from before the load was read)."""
        return {e.short: Load.from_metrics(e.figures, LATENCY_METRIC) for e in self.timed()}

    def latency_front(self) -> dict:
        """The Pareto front of render RMSE against latency, with noise.

        Returns ``points`` (``{name: (latency ms, render RMSE, low, high)}``: the rows with both),
        ``within_noise`` (the pairs of them whose 95% paired bootstrap interval of the render RMSE
        difference contains 0, as in "what accuracy costs"), ``front`` (names, by latency) and
        ``dominated`` (``{name: the fastest row that dominates it}``, see
        :func:`svbrdf_bench.plots.dominated_by`).
        """
        from ..metrics import paired_difference
        from ..plots import dominated_by

        key = tuple((e.run_id, e.figures.get("time/latency_ms")) for e in self.models)
        if self._front_cache.get("key") == key:  # the report text and the plot ask alike
            return self._front_cache["front"]
        rows, points = {}, {}
        for e in self.timed():
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

    # -- one record per row ---------------------------------------------------------------------

    def records(self) -> list[dict]:
        """One flat record per row (results.csv, the ``models`` of results.json): its identity,
        each accuracy figure with its 95% interval (``rmse_render``, ``rmse_render_low``, ...), its
        time and size figures, the load while timing, and its re-rendering figures."""
        out = []
        for e in self.models:
            rec = {"model": e.label, "baseline": e.baseline, "reference": e.is_reference, "run_id": e.run_id}
            if self.refined:
                rec |= {"refine_steps": e.refine_steps, "refined_from": e.base_label or "-",
                        "pure_optimisation": e.pure_optimisation}  # fmt: skip
            rec["train_run_id"] = "-" if e.baseline or e.is_reference else e.train_run_id
            if e.seed is not None:  # a fit's row: its seed and training budget
                rec |= {"seed": e.seed, "budget": e.budget_text}
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
                if key.startswith(_RECORDED) and key not in rec:
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
