"""What the MLflow UI shows of a finished benchmark: the parent run's description (the verdict,
links to the report and to every row's run, each row's RMSE per map), its metrics (each row's
figures, named so that they sort by row), the test set as every run's dataset input, and a saved
view of the experiment's runs grouped by benchmark (:func:`describe_in_mlflow`).

Everything here is read from the report's results.json, written before.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from svbrdf_render import MAP_NAMES

from .inference import FLOPS_METRIC
from .layout import PARENT_TAG, REPORT_ARTIFACTS
from .testset import TestSet

__all__ = [
    "BENCHMARK_TAG",
    "BENCH_VIEW",
    "BENCH_VIEW_NAME",
    "BENCH_COLUMNS",
    "metric_prefix",
    "parent_metrics",
    "parent_note",
    "describe_in_mlflow",
]

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
    "test/ssim/render", "time/latency_ms", "model/params", FLOPS_METRIC,
)  # fmt: skip
#: Maps of the table in the parent run's description.
NOTE_COLUMNS = ("render", *MAP_NAMES)
#: MLflow truncates a run tag's value beyond 8000 characters: the description's table goes first.
NOTE_LIMIT = 7500
#: The fields of a row of results.json that become the parent run's metrics: accuracy (with the
#: bounds of its intervals) and re-rendering figures, then these time and size figures; the rest
#: (memory, throughput, the load while timing) stays in results.csv, not to bury the comparison
#: under a hundred charts.
METRIC_FIELDS = ("rmse_", "ssim_", "lpips_", "photo_rerender_rmse", "real_rerender_rmse")
TIME_FIELDS = (
    "time_latency_ms", "time_latency_iqr_ms", "time_train_s", "time_seconds_per_image", "model_params",
    FLOPS_METRIC.replace("/", "_"),
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
    from svbrdf_train import ui_page

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


def describe_in_mlflow(client, parent, test: TestSet, out: Path, test_data: str | None, sha: str) -> str:
    """What the MLflow UI shows of the finished benchmark (the report is already logged):

    - the parent run: its description (:func:`parent_note`), its metrics (:func:`parent_metrics`),
      the test set as a dataset input;
    - each child run: the test set as its dataset input (context ``test``), the benchmark it
      belongs to (:data:`BENCHMARK_TAG`), and where it comes from (``svbrdf-bench run`` at this
      commit; a fit trained here keeps its own, ``svbrdf-train fit``);
    - the experiment: the saved view :data:`BENCH_VIEW` of its runs.

    ``out``: the report folder (its results.json); ``test_data``: the ``--test-data`` given (None:
    procedural). Returns the view's key.
    """
    from mlflow.entities import Metric, RunTag

    from svbrdf_train import log_datasets, source_tags, test_dataset

    from .presets import TEST_SEED

    results = json.loads((Path(out) / "results.json").read_text())
    parent_id, experiment = parent.run_id, parent.experiment_id
    name = client.get_run(parent_id).info.run_name
    dataset = test_dataset(test_data, test.resolution, count=len(test), seed=TEST_SEED)
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
