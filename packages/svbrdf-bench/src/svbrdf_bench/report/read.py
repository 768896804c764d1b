"""A benchmark's :class:`~svbrdf_bench.report.figures.Report`, read back from MLflow alone: the parent
run (its params: preset, test set, budgets, grouping) and one row per evaluated child run, laid
out as :mod:`svbrdf_bench.layout` describes (this module never imports the runner that writes
them). A refined row follows the row it refined (:func:`link_refined`).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

from ..errors import BenchError
from ..layout import (
    BASELINES_PARAM,
    BENCH_KIND,
    BUDGET_PREFIX,
    BUDGETS_PARAM,
    FIT_WALL_METRIC,
    GROUP_BY_PARAM,
    KIND_TAG,
    LPIPS_TAG,
    MINUTES_PARAM,
    MISSED_BUDGETS,
    MODEL_SHA_TAG,
    MODEL_SOURCE_TAG,
    MODEL_TAG,
    PARENT_TAG,
    PER_SAMPLE,
    PRESET_PARAM,
    PUBLISHED,
    PUBLISHED_PARAM,
    REAL_DATA_PARAM,
    REFINE_BACKEND_PARAM,
    REFINE_FLASH_PARAM,
    REFINE_PARAM,
    REFINED_FROM_TAG,
    STEPS_METRIC,
    STEPS_WALL_METRIC,
    TEST_GROUPS,
    TEST_RESOLUTION_PARAM,
    TEST_SET_PARAM,
    TRAINER_PREFIXES,
    is_baseline,
    read_missed,
    read_per_sample,
    read_phases,
    read_test_groups,
    reference_name,
    refine_steps,
    train_run_id,
)
from .figures import Report
from .rows import INHERITED, ModelEntry
from .seedstats import one_curve_per_fit, tag_entry

__all__ = ["build_report", "link_refined"]


def build_report(parent_id: str) -> Report:
    """Everything the report shows, read back from the parent run and its children."""
    from mlflow import MlflowClient

    from svbrdf_train import check_store, tracking_uri

    check_store(tracking_uri())  # a file that is not an MLflow store is refused before MLflow writes to it
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
    with tempfile.TemporaryDirectory() as tmp:
        models = [tag_entry(_entry(client, child, tmp), child.data.tags)  # seed, model, budget
                  for child in sorted(children, key=lambda r: r.info.start_time)]  # fmt: skip
    models = [e for e in models if e is not None]  # None: trained but never evaluated (interrupted)
    one_curve_per_fit(models)
    if not models:
        raise BenchError(f"run {parent_id} has no evaluated models yet")
    params = parent.data.params
    minutes = params.get(MINUTES_PARAM, "?")
    return Report(
        parent_id=parent_id,
        preset=params.get(PRESET_PARAM, "?"),
        test_set=params.get(TEST_SET_PARAM, "?"),
        lpips_note=parent.data.tags.get(LPIPS_TAG, ""),
        minutes=f"{minutes} min of training per model" if minutes[:1].isdigit() else minutes,
        models=link_refined(models),
        real_data=params.get(REAL_DATA_PARAM, "-"),
        baselines=params.get(BASELINES_PARAM),
        refine={
            k: params[k] for k in (REFINE_PARAM, REFINE_BACKEND_PARAM, REFINE_FLASH_PARAM) if k in params
        },
        phases=read_phases(parent.data.metrics),
        missed_budgets=_missed(client, parent_id, params),
        published=_published(client, parent_id, params),
        resolution=int(side) if (side := params.get(TEST_RESOLUTION_PARAM, "")).isdigit() else None,
        **_grouping(client, parent_id, params),
    )


def _entry(client, child, tmp: str) -> ModelEntry | None:
    """The row of one child run: a refined row, a baseline, a reference model file or a fit;
    None for a child that was never evaluated."""
    label = child.data.tags.get(MODEL_TAG)
    if label is None:
        return None
    tags = child.data.tags
    local = client.download_artifacts(child.info.run_id, PER_SAMPLE, tmp)
    per_sample = read_per_sample(Path(local).read_text())
    train_run = train_run_id(child.info.run_id, tags)
    metrics = child.data.metrics
    figures = {k: v for k, v in metrics.items() if not k.startswith(TRAINER_PREFIXES)}
    row = (label, child.info.run_id, train_run, per_sample, figures)  # what every entry has
    steps = refine_steps(tags)
    if steps:  # a row refined for `steps`: linked to the row it refined by link_refined
        return ModelEntry(*row, baseline=is_baseline(tags), reference_name=reference_name(tags),
                          refine_steps=steps, refined_from=tags.get(REFINED_FROM_TAG))  # fmt: skip
    if is_baseline(tags):
        return ModelEntry(*row, baseline=True)
    figures[STEPS_METRIC] = metrics.get(STEPS_METRIC, math.nan)
    short = reference_name(tags)
    if short is not None:  # a model file trained elsewhere: no fit, no learning curve here
        budget = {"source": tags.get(MODEL_SOURCE_TAG, "?"), "sha256": tags.get(MODEL_SHA_TAG, "?")}
        params = child.data.params
        budget |= {k[len(BUDGET_PREFIX) :]: v for k, v in params.items() if k.startswith(BUDGET_PREFIX)}
        return ModelEntry(*row, reference_name=short, budget=budget)
    if STEPS_WALL_METRIC not in figures and FIT_WALL_METRIC in metrics:
        figures[STEPS_WALL_METRIC] = metrics[FIT_WALL_METRIC]
    return _fit_entry(client, row, tags if train_run == child.info.run_id else None)


def _fit_entry(client, row: tuple, tags: dict | None) -> ModelEntry:
    """The row of a fit (trained here, or reused: ``tags`` None, read from its own run): its
    learning curves, its budget clock, and where a fine-tuned fit started."""
    from svbrdf_train import CLOCK_TAG

    train_run = row[2]
    tags = tags if tags is not None else client.get_run(train_run).data.tags
    before = float(tags.get("svbrdf.init_train_seconds", 0.0))
    init = (tags["svbrdf.init"], before) if "svbrdf.init" in tags else None
    return ModelEntry(
        *row,
        _curve(client, train_run, offset=before),
        _curve(client, train_run, "val_real/rmse/render", offset=before),
        clock=tags.get(CLOCK_TAG),
        init=init,
    )


def _curve(
    client, run_id: str, key: str = "val/rmse/render", offset: float = 0.0
) -> tuple[list[float], list[float]]:
    """``(training seconds, metric)`` at the validation steps of a fit (``key``: which figure);
    ``offset``: training time before the fit (a fine-tuned fit's starting weights)."""
    rmse = {m.step: m.value for m in client.get_metric_history(run_id, key)}
    seconds = {m.step: m.value for m in client.get_metric_history(run_id, "val/train_seconds")}
    steps = sorted(set(rmse) & set(seconds))
    return [offset + seconds[s] for s in steps], [rmse[s] for s in steps]


def _grouping(client, parent_id: str, params: dict) -> dict:
    """How the test samples group into materials (the parent's ``eval/test_groups.json``), as
    :class:`Report` fields; empty when per image (procedural test sets, older runs, a lost file)."""
    if params.get(GROUP_BY_PARAM) not in ("des18", "file"):
        return {}
    with tempfile.TemporaryDirectory() as tmp:
        try:
            local = client.download_artifacts(parent_id, TEST_GROUPS, tmp)
        except Exception:  # recorded as grouped but the artifact is gone: per image, as before
            return {}
        group_by, names, groups = read_test_groups(Path(local).read_text())
    return {"group_by": group_by, "sample_names": names, "groups": groups}


def _missed(client, parent_id: str, params: dict) -> list[dict]:
    """The training budgets a fit never reached (the parent's ``eval/missed_budgets.json``); empty
    without several budgets (param ``train_budgets``) or when every fit reached them."""
    if "," not in params.get(BUDGETS_PARAM, ""):
        return []
    with tempfile.TemporaryDirectory() as tmp:
        try:
            local = client.download_artifacts(parent_id, MISSED_BUDGETS, tmp)
        except Exception:  # absent: every fit reached every budget
            return []
        return read_missed(Path(local).read_text())


def _published(client, parent_id: str, params: dict):
    """The published numbers the benchmark set beside its rows (the parent's ``eval/published.yaml``,
    read as ``--published`` read it); None without ``--published``. A run that records the file
    but lost it is refused: its rows would go missing without a word."""
    from ..published import parse_published

    origin = params.get(PUBLISHED_PARAM)
    if origin is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        try:
            local = client.download_artifacts(parent_id, PUBLISHED, tmp)
        except Exception as e:
            raise BenchError(
                f"run {parent_id} records published numbers ({origin}) but its {PUBLISHED} cannot be read "
                f"({type(e).__name__})"
            ) from None
        return parse_published(Path(local).read_text(encoding="utf-8"), origin)


def link_refined(models: list[ModelEntry]) -> list[ModelEntry]:
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
        e.figures = {k: base.figures[k] for k in INHERITED if k in base.figures} | e.figures
        children.setdefault(base.run_id, []).append(e)
    out = []
    for e in models:
        if not e.refine_steps:
            out += [e, *sorted(children.get(e.run_id, []), key=lambda r: r.refine_steps)]
    return out + orphans
