"""The benchmark's runs in MLflow, one child run of the parent per row: a fit trained here (in its
own process, as a user would: :func:`train`; its checkpoint: :func:`fit_checkpoint`), a reused
fit (:func:`resolve_reuse`, :func:`reused_child`), a baseline (:func:`baseline_child`) and the
refined rows of any of them (:func:`log_refined_children`); each evaluated child gets its
figures and per-sample values (:func:`log_child`), laid out as :mod:`svbrdf_bench.layout`
describes.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import BenchError
from .layout import (
    MODEL_TAG,
    PARENT_TAG,
    PER_SAMPLE,
    REFERENCE_TAG,
    REFINE_TAG,
    REFINED_FROM_TAG,
    TRAIN_RUN_TAG,
    baseline_tags,
    per_sample_json,
)
from .options import BenchOptions
from .refinement import RefinedRow, RefinePlan, refined_label
from .scoring import test_means

__all__ = [
    "tracking_client",
    "resolve_reuse",
    "train",
    "fit_checkpoint",
    "log_child",
    "log_refined_children",
    "baseline_child",
    "reused_child",
]


def tracking_client():
    """The client of the tracking store, which is created (quietly, one process at a time) if new."""
    import mlflow

    from svbrdf_train import open_client

    return open_client(mlflow.get_tracking_uri())


def resolve_reuse(items: Sequence[str]) -> list[tuple[str, str]]:
    """``--from-runs`` items (run ids or recipe names) -> ``(model label, run id)``."""
    client = tracking_client()
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


def train(model: str, options: BenchOptions, parent: str, work: Path) -> tuple[str, float, Path]:
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


def fit_checkpoint(run_id: str, local: Path | None) -> dict:
    """The fit's checkpoint: the file it wrote here, else the weights logged in its run (or an
    older run's whole checkpoint)."""
    from svbrdf_train import load_checkpoint

    if local is None:
        from svbrdf_train import download_run_checkpoint

        return download_run_checkpoint(run_id)
    return load_checkpoint(local, source=f"the checkpoint of MLflow run {run_id}")


# -- evaluation ---------------------------------------------------------------------------------


def log_child(run_id: str, figures: dict[str, float], per_sample: dict[str, np.ndarray], work: Path) -> None:
    from mlflow.entities import Metric

    client = tracking_client()
    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(k, float(v), now, 0) for k, v in figures.items()])
    target = work / f"eval-{run_id}" / Path(PER_SAMPLE).name
    target.parent.mkdir(exist_ok=True)
    target.write_text(per_sample_json(per_sample))
    client.log_artifact(run_id, str(target), str(Path(PER_SAMPLE).parent))


def log_refined_children(
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
        figures = row.figures | test_means(row.per_sample) | {"model/params": params}
        log_child(child, figures, row.per_sample, work)
        client.set_terminated(child)


def baseline_child(client, experiment_id: str, parent_id: str, name: str) -> tuple[str, object]:
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


def reused_child(client, experiment_id: str, parent_id: str, label: str, source: str) -> str:
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
