"""``svbrdf-bench run``: train (or reuse) each model, evaluate all on one test set, log and report.

Model files trained elsewhere (``--from-models``, ``--models pretrained``) are scored beside them
as reference rows (:mod:`svbrdf_bench.references`): same test images, same figures, a label that
says they are not equal-budget competitors.

``--refine 0,50,200`` adds, per scored row and budget, a row of its maps refined against each
test photo (:mod:`svbrdf_bench.refinement`), each a child run of its own; with ``--real-data``
too, each refined row also refines its maps of each real photo (the real-photo figure), and the
report gets a real-photo sheet: each model's maps and re-renderings, its refined ones under it.

Each invocation is one MLflow parent run with a child run per model and per baseline, laid out
as :mod:`svbrdf_bench.layout` describes; :mod:`svbrdf_bench.report` builds every table and plot
from those runs alone, so ``svbrdf-bench report PARENT`` rebuilds them later.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from svbrdf_render.files import check_output_folder

from .errors import BenchError
from .layout import (
    BASELINE_TAG,
    BASELINES_PARAM,
    BENCH_KIND,
    FIT_WALL_METRIC,
    GROUP_BY_PARAM,
    KIND_TAG,
    LPIPS_TAG,
    MINUTES_PARAM,
    MODEL_TAG,
    PARENT_TAG,
    PER_SAMPLE,
    PRESET_PARAM,
    REAL_DATA_PARAM,
    REAL_PREFIX,
    REAL_RERENDER,
    REFERENCE_TAG,
    REFERENCES_PARAM,
    REFINE_BACKEND_PARAM,
    REFINE_FLASH_PARAM,
    REFINE_PARAM,
    REFINE_TAG,
    REFINED_FROM_TAG,
    REPORT_ARTIFACTS,
    STEPS_METRIC,
    STEPS_WALL_METRIC,
    TEST_GROUPS,
    TEST_PREFIX,
    TEST_SET_PARAM,
    TRAIN_RUN_TAG,
    baseline_tags,
    per_sample_json,
    test_groups_json,
)
from .presets import Preset
from .references import (
    check_resolution,
    check_trained_strips,
    load_references,
    reference_child,
    reference_figures,
    split_pretrained,
)
from .refinement import RefinedRow, RefinePlan, refine_real, refine_rows, refined_label
from .testset import TestSet

__all__ = ["BenchOptions", "run_bench", "BASELINES", "metric_prefix", "parent_metrics", "parent_note"]

#: The baselines every benchmark evaluates unless told not to (svbrdf_models.baselines).
BASELINES = ("mean", "photo")
#: Test samples shown in the visual comparison grid.
GRID_SAMPLES = 3
#: Tiles of the comparison grid smaller than this many pixels are enlarged.
GRID_MIN_SIZE = 96
#: Side of the input of the latency measurement.
LATENCY_SIZE = 256


@dataclass
class BenchOptions:
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
    """How real test samples are grouped into materials (svbrdf_train.data.materials.GROUP_BY)."""
    say: Callable[[str], None] = print


def _client():
    """The client of the tracking store, which is created (quietly, one process at a time) if new."""
    import mlflow

    from svbrdf_train.tracking import open_client

    return open_client(mlflow.get_tracking_uri())


# -- models -------------------------------------------------------------------------------------


def _resolve_reuse(items: Sequence[str]) -> list[tuple[str, str]]:
    """``--from-runs`` items (run ids or recipe names) -> ``(model label, run id)``."""
    client = _client()
    out = []
    for item in items:
        try:
            run = client.get_run(item)
        except Exception:  # not a run id: a recipe name
            run = None
        if run is not None and TRAIN_RUN_TAG in run.data.tags:  # a benchmark's child of a reused fit
            run = client.get_run(run.data.tags[TRAIN_RUN_TAG])
        if run is not None:
            label = run.data.tags.get("recipe") or item
            if any(label == seen for seen, _ in out):  # two fits of one recipe: tell them apart
                label = run.info.run_name or f"{label}-{run.info.run_id[:8]}"
            out.append((label, run.info.run_id))
            continue
        experiments = [e.experiment_id for e in client.search_experiments()]
        found = [
            r  # the fits themselves, not the benchmark children that only point at one
            for r in client.search_runs(
                experiments,
                filter_string=f"tags.recipe = '{item}' and attributes.status = 'FINISHED'",
                order_by=["attributes.end_time DESC"],
                max_results=50,
            )
            if TRAIN_RUN_TAG not in r.data.tags
        ]
        if not found:
            raise BenchError(
                f"--from-runs {item}: neither a run id nor the recipe of a finished run "
                f"in {client.tracking_uri}"
            )
        out.append((item, found[0].info.run_id))
    return out


def _check_models(models: Sequence[str]) -> None:
    from svbrdf_train.recipe import list_recipes

    known = list_recipes()
    for m in models:
        if m not in known and Path(m).suffix not in (".yaml", ".yml"):
            import difflib

            close = difflib.get_close_matches(m, known, n=2, cutoff=0.5)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            raise BenchError(f"unknown model {m!r}{hint}; models are recipes: {', '.join(known)}")


def _train(model: str, options: BenchOptions, parent: str, work: Path) -> tuple[str, float, Path]:
    """Train one recipe in its own process (as a user would); its run id, wall seconds and checkpoint."""
    p = options.preset
    minutes = options.minutes if options.minutes is not None else p.minutes
    out = work / Path(model).stem
    size = options.size or p.size
    cmd = [
        sys.executable, "-m", "svbrdf_train", "fit",
        "--recipe", model, "--size", size, "--out", str(out), "--force",
        "--experiment", options.experiment, "--parent-run", parent, "--run-name", Path(model).stem,
        "--set", f"train.validate_every={p.validate_every}", "--device", options.device,
    ]  # fmt: skip
    if minutes is not None:
        cmd += ["--max-minutes", str(minutes)]
    for item in (*p.overrides, *options.overrides):
        cmd += ["--set", item]
    start = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise BenchError(f"training {model} failed (exit {done.returncode}); its messages are above")
    summary = json.loads((out / "last.json").read_text())
    return summary["run_id"], wall, out / "last.pt"


def _checkpoint(run_id: str, local: Path | None) -> dict:
    """The fit's checkpoint: the file it wrote here, else the weights logged in its run (or an
    older run's whole checkpoint)."""
    from svbrdf_train.checkpoint import load_checkpoint

    if local is None:
        from svbrdf_train.init import download_run_checkpoint

        return download_run_checkpoint(run_id)
    return load_checkpoint(local, source=f"the checkpoint of MLflow run {run_id}")


# -- evaluation ---------------------------------------------------------------------------------


@torch.no_grad()
def _evaluate(generator, test: TestSet, device: torch.device, lpips) -> tuple[dict[str, np.ndarray], list]:
    from torch.utils.data import DataLoader

    from svbrdf_render import SVBRDF

    from .metrics import evaluate

    parts: dict[str, list[np.ndarray]] = {}
    shown = []
    for batch in DataLoader(test, batch_size=8):
        photo = batch["input"].to(device)
        target = SVBRDF.unpack(batch["maps"].to(device), validate=False)
        pred = generator(photo)
        for k, v in evaluate(pred, target, lpips=lpips).items():
            parts.setdefault(k, []).append(np.asarray(v, dtype=np.float64))
        if len(shown) < GRID_SAMPLES:
            shown += [(photo[i].cpu(), pred[i : i + 1].to("cpu"), target[i : i + 1].to("cpu"))
                      for i in range(min(GRID_SAMPLES - len(shown), photo.shape[0]))]  # fmt: skip
    return {k: np.concatenate(v) for k, v in parts.items()}, shown


def _self_consistency(generator, photos, resolution: int, device: torch.device) -> np.ndarray:
    """Per photo: RMSE of the predicted maps re-rendered under the flash fitted to the photo.

    The photo's centre square at the model's resolution is predicted, then the capture tool's
    :func:`~svbrdf_train.capture.flash_consistency` finds the flash that re-renders those maps
    closest to the photo; its RMSE (clipped re-rendering against the photo) is the figure.
    """
    from svbrdf_train.capture import flash_consistency
    from svbrdf_train.data.photos import square_photo

    out = []
    for i in range(len(photos)):
        x = square_photo(photos[i]["input"], resolution).to(device)[None]
        with torch.no_grad():
            maps = generator(x)
        out.append(float(flash_consistency(maps, x).rmse[0]))
    return np.asarray(out, dtype=np.float64)


@torch.no_grad()
def _latency(generator, device: torch.device, repeats: int) -> dict[str, float]:
    """Inference time of one image of ``LATENCY_SIZE``: ``repeats`` timed runs after 3 warm-up
    runs (:func:`svbrdf_bench.timing.time_call`), as metrics ``time/latency_ms`` (the median),
    ``time/latency_iqr_ms``, ``time/latency_runs`` and the machine's load while they ran.

    On the CPU with one torch thread, as the fits train: on an idle 2-core machine two threads
    spread the runs by 5-14% of the median against 4-6% with one (50 runs of the cpu-size
    generators), and a second thread is the first to wait when anything else runs."""
    from .timing import LATENCY_METRIC, time_call

    x = torch.rand(1, 3, LATENCY_SIZE, LATENCY_SIZE, device=device)
    if device.type != "cpu":
        return time_call(lambda: generator(x), repeats, warmup=3).metrics(LATENCY_METRIC)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return time_call(lambda: generator(x), repeats, warmup=3, threads=1).metrics(LATENCY_METRIC)
    finally:
        torch.set_num_threads(threads)


def _step_spread(client, run_id: str, batch: int) -> dict[str, float]:
    """Median and IQR of the fit's training time per step over its logging windows (its
    ``train/samples_per_s`` history, the first window left out: it pays for warm-up), as
    ``time/train_ms_per_step_median`` and ``time/train_ms_per_step_iqr``; empty under 4 windows."""
    from .timing import summarize

    history = sorted(client.get_metric_history(run_id, "train/samples_per_s"), key=lambda m: m.step)
    rates = [m.value for m in history[1:] if m.value > 0 and np.isfinite(m.value)]
    if len(rates) < 4:
        return {}
    t = summarize([1000 * batch / r for r in rates])
    return {"time/train_ms_per_step_median": t.median_ms, "time/train_ms_per_step_iqr": t.iqr_ms}


def _log_child(run_id: str, figures: dict[str, float], per_sample: dict[str, np.ndarray], work: Path) -> None:
    from mlflow.entities import Metric

    client = _client()
    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(k, float(v), now, 0) for k, v in figures.items()])
    target = work / f"eval-{run_id}" / Path(PER_SAMPLE).name
    target.parent.mkdir(exist_ok=True)
    target.write_text(per_sample_json(per_sample))
    client.log_artifact(run_id, str(target), str(Path(PER_SAMPLE).parent))


def _test_means(per_sample: dict[str, np.ndarray]) -> dict[str, float]:
    """The ``test/`` metrics: the mean of each per-sample figure on the test images."""
    return {
        f"{TEST_PREFIX}{k}": float(v.mean()) for k, v in per_sample.items() if not k.startswith(REAL_PREFIX)
    }


def _refined_children(
    client, experiment_id: str, parent_id: str, base: tuple[str, str, dict[str, str]],
    rows: dict[int, RefinedRow], plan: RefinePlan, params: float, work: Path,
) -> None:  # fmt: skip
    """A child run per refined budget of the row ``base`` = ``(label, child run id, extra tags)``;
    the extra tags (svbrdf.baseline, svbrdf.reference: a reference's short name) are the row's."""
    from mlflow.entities import Param

    label, base_run, extra = base
    name = extra.get(REFERENCE_TAG)
    for k, row in sorted(rows.items()):
        tags = {PARENT_TAG: parent_id, MODEL_TAG: refined_label(label, k, name), REFINE_TAG: str(k),
                REFINED_FROM_TAG: base_run, **extra}  # fmt: skip
        run_name = refined_label(name, k) + " (reference)" if name else refined_label(label, k)
        child = client.create_run(experiment_id, run_name=run_name, tags=tags).info.run_id
        client.log_batch(child, params=[Param(a, b) for a, b in plan.params(k).items()])
        figures = row.figures | _test_means(row.per_sample) | {"model/params": params}
        _log_child(child, figures, row.per_sample, work)
        client.set_terminated(child)


def _check_baselines(baselines: Sequence[str], labels: Sequence[str]) -> None:
    import svbrdf_models as sm

    known = sm.list_models("generator")
    for name in baselines:
        if name not in known:
            raise BenchError(f"unknown baseline {name!r}; registered generators: {', '.join(known)}")
        if name in labels:
            raise BenchError(
                f"model {name!r} has the name of a baseline; rename the recipe or use --no-baselines"
            )


def _baseline_child(client, experiment_id: str, parent_id: str, name: str) -> tuple[str, object]:
    """A child run for baseline ``name`` and its generator (built from the registry, untrained)."""
    from mlflow.entities import Param

    import svbrdf_models as sm

    config = sm.resolve_config("generator", name)
    child = client.create_run(
        experiment_id,
        run_name=f"{name} (baseline)",
        tags=baseline_tags(parent_id, name),
    )
    params = [Param(f"model.{k}", str(v)) for k, v in sm.config_to_dict(config).items()]
    client.log_batch(child.info.run_id, params=[Param("model.name", name), *params])
    return child.info.run_id, sm.create_generator(name).eval()


def _reused_child(client, experiment_id: str, parent_id: str, label: str, source: str) -> str:
    """The child run of a reused fit ``source``: tagged with it, and carrying its params (the whole
    recipe, the networks' configs, parameter counts), as the child of a fit trained here does, being
    that fit's own run. Returns the child's run id."""
    from mlflow.entities import Param

    fitted = client.get_run(source)
    child = client.create_run(
        experiment_id,
        run_name=f"{label} (reused)",
        tags={
            PARENT_TAG: parent_id,
            TRAIN_RUN_TAG: source,
            "recipe": fitted.data.tags.get("recipe", label),
        },
    )
    params = [Param(k, v) for k, v in sorted(fitted.data.params.items())]
    for start in range(0, len(params), 100):  # MLflow takes at most 100 params per batch
        client.log_batch(child.info.run_id, params=params[start : start + 100])
    return child.info.run_id


# -- what the MLflow UI shows ------------------------------------------------------------------

#: Tag of a benchmark's child runs: the benchmark they belong to, ``RUN_NAME (PARENT_ID[:8])``; the
#: saved view :data:`BENCH_VIEW` groups the runs by it.
BENCHMARK_TAG = "svbrdf.benchmark"
#: The saved view of a benchmark experiment's runs page: every benchmark's rows (its child runs,
#: one per model, baseline, reference and refined row), grouped by benchmark, newest first, with
#: these test figures as columns. The links the benchmark gives open it.
BENCH_VIEW = "svbrdf-benchmarks"
BENCH_VIEW_NAME = "svbrdf: benchmarks (test figures)"
BENCH_COLUMNS = (
    "test/rmse/render", "test/rmse/normal", "test/rmse/diffuse", "test/rmse/roughness", "test/rmse/specular",
    "test/ssim/render", "time/latency_ms", "model/params",
)  # fmt: skip
#: Maps of the table in the parent run's description.
NOTE_COLUMNS = ("render", "normal", "diffuse", "roughness", "specular")
#: MLflow truncates a run tag's value beyond 8000 characters: the description's table goes first.
NOTE_LIMIT = 7500
#: The fields of a row of results.json that become the parent run's metrics: accuracy (with the
#: bounds of its intervals) and re-rendering figures, then these time and size figures; the rest
#: (memory, throughput, the load while timing) stays in results.csv, not to bury the comparison
#: under a hundred charts.
METRIC_FIELDS = ("rmse_", "ssim_", "lpips_", "photo_rerender_rmse", "real_rerender_rmse")
TIME_FIELDS = (
    "time_latency_ms", "time_latency_iqr_ms", "time_train_s", "time_seconds_per_image", "model_params",
)  # fmt: skip


def metric_prefix(record: dict) -> str:
    """The name a row of ``results.json`` takes in the parent run's metrics: its label (a
    reference row: its short name and ``reference``), with every run of characters MLflow refuses in
    a metric name, or that sorts badly, made one ``_``: ``ours``, ``no-attn``, ``ours_refine_50``,
    ``fold0_reference``."""
    import re

    name = record["model"]
    if record.get("reference"):
        steps = record.get("refine_steps") or 0
        name = f"{record.get('reference_name') or name}{f' +refine {steps}' if steps else ''} reference"
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "row"


def parent_metrics(results: dict) -> dict[str, float]:
    """The comparison's figures as the parent run's metrics: the accuracy figures of every row of
    ``results.json`` (:data:`METRIC_FIELDS`, named as in results.csv) and its main time figures
    (:data:`TIME_FIELDS`), as ``PREFIX/FIELD`` (:func:`metric_prefix`), the bounds of a 95% bootstrap
    interval renamed ``_lower`` and ``_upper`` so that they sort after the mean: ``ours/rmse_render``,
    ``ours/rmse_render_lower``, ``ours/rmse_render_upper``, ``ours/ssim_normal``, ``ours/time_latency_ms``,
    ``mean/rmse_render``... Non-finite figures are left out."""
    import math

    out: dict[str, float] = {}
    seen: set[str] = set()
    for i, rec in enumerate(results["models"]):
        prefix = metric_prefix(rec)
        if prefix in seen:  # two labels that differ only in characters a metric name cannot have
            prefix = f"{prefix}_{i}"
        seen.add(prefix)
        for key, value in rec.items():
            if isinstance(value, bool) or not isinstance(value, int | float):
                continue
            if not (key.startswith(METRIC_FIELDS) or key in TIME_FIELDS):
                continue
            if not math.isfinite(value):
                continue
            if key.endswith("_low"):
                key = key[: -len("_low")] + "_lower"
            elif key.endswith("_high"):
                key = key[: -len("_high")] + "_upper"
            out[f"{prefix}/{key}"] = float(value)
    return out


def parent_note(results: dict, experiment_id: str, parent_id: str) -> str:
    """The parent run's description (markdown, the UI's "Description"): the report's headline (the
    verdict), links to the report (an artifact of the run) and to every row's run, the report's
    timing warning, then each row's RMSE per map with its 95% bootstrap interval."""
    from svbrdf_train.tracking import ui_page

    report = ui_page(experiment_id, parent_id, artifact=f"{REPORT_ARTIFACTS}/report.md")
    rows = ui_page(experiment_id, view=BENCH_VIEW)
    models = [rec["model"] for rec in results["models"]]
    # The verdict first: the UI shows the first three lines or so until "Show more" is clicked.
    lines = [f"**{h}**" for h in results.get("headline") or [f"Benchmark of {', '.join(models)}."]]
    lines.append(f"[Full report]({report}) · [every row's run]({rows})")
    if results.get("timing_warning"):
        lines.append(f"**{results['timing_warning']}**")
    head = "| row | " + " | ".join(f"{c} RMSE [95%]" for c in NOTE_COLUMNS) + " |"
    table = [head, "|---" * (len(NOTE_COLUMNS) + 1) + "|"]
    for rec in results["models"]:
        cells = []
        for c in NOTE_COLUMNS:
            k = f"rmse_{c}"
            if k in rec and f"{k}_low" in rec:
                cells.append(f"{rec[k]:.4f} [{rec[k + '_low']:.4f}, {rec[k + '_high']:.4f}]")
            else:
                cells.append("-")
        table.append(f"| {rec['model']} | " + " | ".join(cells) + " |")
    words = (
        f"Test set: {results.get('test_set', '?')}; "
        f"means over {results.get('averaged_over', 'test images')}. "
        "This run's metrics hold each row's figures: `ROW/rmse_MAP` with `ROW/rmse_MAP_lower` and "
        "`ROW/rmse_MAP_upper` (the interval), SSIM likewise, and its main times (`ROW/time_latency_ms`...). "
        f"The report is this run's artifact report/report.md; `svbrdf-bench report {parent_id}` rebuilds it."
    )
    note = "\n\n".join([*lines, "\n".join(table), words])
    if len(note) > NOTE_LIMIT:
        note = "\n\n".join([*lines, words])
    return note[:NOTE_LIMIT]


def _describe_in_mlflow(client, parent, test, options: BenchOptions, sha: str) -> str:
    """What the MLflow UI shows of the finished benchmark (the report is already logged):

    - the parent run: its description (:func:`parent_note`), its metrics (:func:`parent_metrics`),
      the test set as a dataset input;
    - each child run: the test set as its dataset input (context ``test``), the benchmark it
      belongs to (:data:`BENCHMARK_TAG`), and where it comes from (``svbrdf-bench run`` at this
      commit; a fit trained here keeps its own, ``svbrdf-train fit``);
    - the experiment: the saved view :data:`BENCH_VIEW` of its runs.

    Returns the view's key.
    """
    from mlflow.entities import Metric, RunTag

    from svbrdf_train.tracking import log_datasets, source_tags, test_dataset

    from .presets import TEST_SEED

    results = json.loads((options.out / "results.json").read_text())
    parent_id, experiment = parent.run_id, parent.experiment_id
    name = client.get_run(parent_id).info.run_name
    dataset = test_dataset(options.test_data, test.resolution, count=len(test), seed=TEST_SEED)
    source = source_tags("svbrdf-bench run", sha)
    children = client.search_runs(
        [experiment], filter_string=f"tags.`{PARENT_TAG}` = '{parent_id}'", max_results=50000
    )
    for child in children:
        tags = {BENCHMARK_TAG: f"{name} ({parent_id[:8]})"}
        if "mlflow.source.name" not in child.data.tags:
            tags |= source
        client.log_batch(child.info.run_id, tags=[RunTag(k, v) for k, v in tags.items()])
        log_datasets(client, child.info.run_id, [(dataset, "test")])
    log_datasets(client, parent_id, [(dataset, "test")])
    now = int(time.time() * 1000)
    metrics = [Metric(k, v, now, 0) for k, v in parent_metrics(results).items()]
    for start in range(0, len(metrics), 1000):  # MLflow takes at most 1000 metrics per batch
        client.log_batch(parent_id, metrics=metrics[start : start + 1000])
    parent.set_tags({"mlflow.note.content": parent_note(results, experiment, parent_id)})
    return parent.save_runs_view(
        BENCH_VIEW, BENCH_VIEW_NAME, columns=BENCH_COLUMNS, search=f"tags.`{BENCHMARK_TAG}` LIKE '%'",
        group_by_tag=BENCHMARK_TAG, column_width=130,
    )  # fmt: skip


# -- the whole run ------------------------------------------------------------------------------


def run_bench(options: BenchOptions) -> str:
    """Run the benchmark; returns the parent run id (the report is in ``options.out``)."""
    from svbrdf_train.tracking import git_revision

    from .metrics import load_lpips
    from .report import build_report, write_report

    recipes, shipped = split_pretrained(options.models)
    _check_models(recipes)
    check_output_folder(options.out, "-o")  # before hours of training, not after
    p = options.preset
    size = options.size or p.size
    device = torch.device(options.device)
    refs = load_references(
        [(s, "--models") for s in shipped] + [(s, "--from-models") for s in options.from_models], device
    )
    from svbrdf_train.recipe import load_recipe, parse_overrides

    from .testset import test_set

    def make_test_set(resolution: int):
        test = test_set(options.test_data, resolution, options.test_count or p.test_count, options.group_by)
        if len(test) == 0:
            raise BenchError(f"the test set ({test.description}) is empty")
        return test

    # Arguments are checked before MLflow is touched (a bad path should not wait for a store).
    test = None
    if recipes:
        resolution = load_recipe(
            recipes[0], size, parse_overrides([*p.overrides, *options.overrides])
        ).train.resolution
        check_resolution(refs, resolution, f"the resolution of recipe {recipes[0]!r} at size {size!r}")
        test = make_test_set(resolution)
    reuse = _resolve_reuse(options.from_runs)
    reused_labels = {label for label, _ in reuse}
    to_train = [m for m in recipes if Path(m).stem not in reused_labels]
    if not to_train and not reuse and not refs:
        raise BenchError("no models to compare: give --models, --from-runs and/or --from-models")
    _check_baselines(options.baselines, [Path(m).stem for m in to_train] + list(reused_labels))
    if test is None:
        if reuse:
            resolution = int(_client().get_run(reuse[0][1]).data.params.get("train.resolution", 256))
            why = f"the resolution of the reused fit {reuse[0][0]}"
        else:
            resolution, why = refs[0].model.resolution, f"the resolution of {refs[0].source}"
        check_resolution(refs, resolution, why)
        test = make_test_set(resolution)
    check_trained_strips(refs, test, options.allow_trained_strips, options.say)
    photos = None
    if options.real_data is not None:
        from svbrdf_train.data import PhotoFolder

        photos = PhotoFolder(options.real_data, encoding=options.real_encoding, pattern=options.real_pattern)
    lpips, lpips_note = load_lpips()

    client = _client()
    from svbrdf_train.tracking import MlflowTracker, source_tags, ui_hint

    sha, dirty = git_revision()
    labels = [Path(m).stem for m in to_train] + [label for label, _ in reuse] + [r.short for r in refs]
    minutes = options.minutes if options.minutes is not None else p.minutes
    if to_train:
        budget = "recipe schedule" if minutes is None else str(minutes)
        words = "each recipe's full schedule" if minutes is None else f"{minutes:g} min of training per model"
    elif reuse:
        budget = "reused fits, each with its own training budget (see the time table)"
        words = "reused fits, each with its own training budget"
    else:
        budget = words = "reference models only, each with the training budget its file records"
    if refs and (to_train or reuse):
        words += "; reference rows: their own budgets, not equal"
    parent = MlflowTracker(
        experiment=options.experiment,
        run_name=f"bench-{','.join(labels)}-{p.name}",
        tags={
            KIND_TAG: BENCH_KIND,
            "preset": p.name,
            "models": ",".join(labels),
            "git_sha": sha,
            "git_dirty": str(dirty).lower(),
            "device": str(device),
            "version.torch": torch.__version__,
            LPIPS_TAG: lpips_note,
            **source_tags("svbrdf-bench run", sha),
        },
        params={
            PRESET_PARAM: p.name,
            "recipe_size": size,
            MINUTES_PARAM: budget,
            TEST_SET_PARAM: test.description,
            "test_count": str(len(test)),
            GROUP_BY_PARAM: test.group_by,
            "overrides": " ".join([*p.overrides, *options.overrides]) or "-",
            REAL_DATA_PARAM: f"{len(photos)} photos of {options.real_data} ({options.real_encoding})"
            if photos
            else "-",
            BASELINES_PARAM: ",".join(options.baselines) or "-",
            REFERENCES_PARAM: " ".join(f"{r.source}@{r.model.sha256[:12]}" for r in refs) or "-",
            REFINE_PARAM: ",".join(map(str, options.refine.budgets)),
            **(
                {
                    REFINE_BACKEND_PARAM: options.refine.backend,
                    REFINE_FLASH_PARAM: options.refine.flash_words(),
                }
                if options.refine.active
                else {}
            ),
        },
    )
    parent_id = parent.run_id
    options.say(
        f"benchmark {', '.join(labels)} ({p.name}: {words}); "
        + f"baselines: {', '.join(options.baselines) or 'none'}; test set: {test.description}, "
        + f"{test.grouping_words()}; "
        + f"{lpips_note}"
        + (
            f"; refinement budgets: {', '.join(map(str, options.refine.budgets))} steps "
            f"({options.refine.backend}, flash: {options.refine.flash_words()})"
            if options.refine.active
            else ""
        )
        + f"\n  MLflow parent run: {parent_id}"
    )
    status = "FAILED"
    try:
        with tempfile.TemporaryDirectory(prefix="svbrdf-bench-") as tmp:
            work = Path(tmp)
            if test.groups is not None:  # the report averages per material: which sample shows which
                groups_file = work / Path(TEST_GROUPS).name
                groups_file.write_text(test_groups_json(test.group_by, test.sample_names, test.groups))
                parent.log_artifact(groups_file, str(Path(TEST_GROUPS).parent))
            # label, evaluation run, training wall seconds, reused run, local checkpoint
            jobs: list[tuple[str, str, float | None, str | None, Path | None]] = []
            for i, model in enumerate(to_train, 1):
                options.say(f"[{i}/{len(labels)}] training {model} ({size} size)")
                run_id, wall, local = _train(model, options, parent_id, work)
                jobs.append((Path(model).stem, run_id, wall, None, local))
            for label, source in reuse:
                child = _reused_child(client, parent.experiment_id, parent_id, label, source)
                jobs.append((label, child, None, source, None))
            shown_by_model = {}
            real_by_model: dict[str, list] = {}  # the real-photo sheet (--real-data with --refine)

            def evaluate_one(
                label: str, generator, shown_as: str | None = None
            ) -> tuple[dict[str, float], dict[str, np.ndarray], dict[int, RefinedRow]]:
                """Test images, latency, parameters and real photos: the same for every row; and the
                rows of its refinement budgets (``{steps: RefinedRow}``, empty without --refine)."""
                options.say(f"evaluating {label} on {len(test)} test images")
                per_sample, shown = _evaluate(generator, test, device, lpips)
                figures = {
                    **_latency(generator, device, p.latency_repeats),
                    "model/params": float(sum(q.numel() for q in generator.parameters())),
                }
                if photos is not None:
                    options.say(f"fitting the flash to {len(photos)} real photos with {label}'s maps")
                    real = _self_consistency(generator, photos, test.resolution, device)
                    per_sample[REAL_RERENDER] = real
                    figures[f"{REAL_RERENDER}_median"] = float(np.median(real))
                shown_by_model[shown_as or label] = shown
                refined: dict[int, RefinedRow] = {}
                if options.refine.active:
                    options.say(
                        f"refining {label}'s maps of {len(test)} test images for "
                        f"{', '.join(map(str, options.refine.refined))} steps"
                    )
                    refined = refine_rows(generator, test, device, lpips, options.refine, GRID_SAMPLES)
                    unrefined = refined.pop(0)  # the row itself: its re-rendering of the photo, its time
                    per_sample |= unrefined.per_sample
                    figures |= unrefined.figures
                    top, shown_label = max(refined), shown_as or label
                    grid_label = refined_label(shown_label, top, shown_label.split(" (")[0])
                    shown_by_model[grid_label] = refined[top].shown
                    if photos is not None:
                        options.say(
                            f"refining {label}'s maps of {len(photos)} real photos for "
                            f"{', '.join(map(str, options.refine.refined))} steps"
                        )
                        real_rows = refine_real(generator, photos, test.resolution, device, options.refine,
                                                GRID_SAMPLES)  # fmt: skip
                        for k, row in refined.items():
                            values = real_rows[k][0]
                            row.per_sample[REAL_RERENDER] = values
                            row.figures[f"{REAL_RERENDER}_median"] = float(np.median(values))
                        name = shown_label.split(" (")[0]
                        real_by_model[shown_label] = real_rows[0][1]
                        for k in sorted(refined):
                            real_by_model[refined_label(shown_label, k, name)] = real_rows[k][1]
                figures |= _test_means(per_sample)
                return figures, per_sample, refined

            for label, run_id, wall, source, local in jobs:
                state = _checkpoint(source or run_id, local)
                from svbrdf_train.inference import load_generator

                generator, recipe = load_generator(state, device)
                figures, per_sample, refined = evaluate_one(label, generator)
                train_run = client.get_run(source or run_id)
                m = train_run.data.metrics
                if wall is None and train_run.info.end_time and train_run.info.start_time:
                    wall = (train_run.info.end_time - train_run.info.start_time) / 1000
                rate = m.get("train/steady_samples_per_s")
                figures |= {
                    "time/train_wall_s": wall or float("nan"),
                    "time/train_s": m.get("train/total_seconds", float("nan")),
                    "time/train_samples_per_s": rate if rate is not None else float("nan"),
                    "time/train_ms_per_step": 1000 * recipe.train.batch / rate if rate else float("nan"),
                    **_step_spread(client, source or run_id, recipe.train.batch),
                    "memory/peak_rss_mb": m.get("train/peak_rss_mb", float("nan")),
                    STEPS_METRIC: float(state["step"]),
                }
                if FIT_WALL_METRIC in m:
                    figures[STEPS_WALL_METRIC] = m[FIT_WALL_METRIC]
                if "train/peak_cuda_mb" in m:
                    figures["memory/peak_cuda_mb"] = m["train/peak_cuda_mb"]
                client.set_tag(run_id, MODEL_TAG, label)
                _log_child(run_id, figures, per_sample, work)
                if source is not None:
                    client.set_terminated(run_id)
                _refined_children(client, parent.experiment_id, parent_id, (label, run_id, {}), refined,
                                  options.refine, figures["model/params"], work)  # fmt: skip
            for ref in refs:  # trained elsewhere: scored, not trained; the label says so
                run_id = reference_child(client, parent.experiment_id, parent_id, ref)
                figures, per_sample, refined = evaluate_one(ref.label, ref.model.generator, ref.short)
                _log_child(run_id, figures | reference_figures(ref), per_sample, work)
                client.set_terminated(run_id)
                _refined_children(client, parent.experiment_id, parent_id,
                                  (ref.label, run_id, {REFERENCE_TAG: ref.name}), refined, options.refine,
                                  figures["model/params"], work)  # fmt: skip
            for name in options.baselines:
                run_id, generator = _baseline_child(client, parent.experiment_id, parent_id, name)
                figures, per_sample, refined = evaluate_one(name, generator.to(device))
                _log_child(run_id, figures, per_sample, work)
                client.set_terminated(run_id)
                base = (name, run_id, {BASELINE_TAG: "true"})
                _refined_children(client, parent.experiment_id, parent_id, base, refined, options.refine,
                                  figures["model/params"], work)  # fmt: skip
            report = build_report(parent_id)
            grid = _comparison_grid(shown_by_model, work / "comparison.png") if shown_by_model else None
            if real_by_model:
                real_grid = _real_grid(real_by_model, work / "real_comparison.png")
                files = write_report(report, options.out, grid=grid, real_grid=real_grid)
            else:
                files = write_report(report, options.out, grid=grid)
            for f in files:
                parent.log_artifact(f, REPORT_ARTIFACTS)
            view = _describe_in_mlflow(client, parent, test, options, sha)
        status = "FINISHED"
        options.say(report.terminal())
        options.say(f"report: {options.out}/report.md; MLflow parent run {parent_id}")
        options.say(f"  MLflow: {ui_hint(parent.uri, parent.experiment_id, view=view)}")
    except KeyboardInterrupt:
        status = "KILLED"
        raise
    finally:
        parent.finish(status)
    return parent_id


def _comparison_grid(shown: dict[str, list], path: Path) -> Path:
    """Per test sample: the input and true maps, then each model's maps; flash re-renderings."""
    from svbrdf_render import linear_to_srgb
    from svbrdf_train.data.sheet import map_tiles
    from svbrdf_train.metrics import display_rendering, preview_flash

    from .plots import comparison_grid

    flash = preview_flash()
    rows = []
    first = next(iter(shown.values()))
    for k, (photo, _, target) in enumerate(first):
        rows.append((f"#{k} truth", [linear_to_srgb(photo), *map_tiles(target.pack()[0]),
                                     display_rendering(target, flash)[0]]))  # fmt: skip
        for label, items in shown.items():
            pred = items[k][1]
            rows.append((f"#{k} {label}", [linear_to_srgb(photo), *map_tiles(pred.pack()[0]),
                                          display_rendering(pred, flash)[0]]))  # fmt: skip
    columns = ["input", "normal", "diffuse", "roughness", "specular", "flash"]
    return comparison_grid(rows, columns, path, min_tile=GRID_MIN_SIZE)


def _real_grid(shown: dict[str, list], path: Path) -> Path:
    """Per real photo: each model's maps and their re-rendering under the flash fitted to them,
    each refined version in the row under its model's (``--real-data`` with ``--refine``)."""
    from svbrdf_render import linear_to_srgb
    from svbrdf_train.data.sheet import map_tiles

    from .plots import comparison_grid

    rows = []
    count = min(len(items) for items in shown.values())
    for k in range(count):
        for label, items in shown.items():
            photo, maps, rendering = items[k]
            rows.append((f"#{k} {label}", [linear_to_srgb(photo), *map_tiles(maps.pack()[0]),
                                          linear_to_srgb(rendering.clamp(0, 1))]))  # fmt: skip
    columns = ["photo", "normal", "diffuse", "roughness", "specular", "fitted flash"]
    return comparison_grid(rows, columns, path, min_tile=GRID_MIN_SIZE)
