"""The MLflow layout of a benchmark: what :mod:`svbrdf_bench.runner` writes and
:mod:`svbrdf_bench.report` reads back (so ``svbrdf-bench report PARENT`` rebuilds a report from
the store alone). Both import these names from here, never from each other's module.

One invocation of ``svbrdf-bench run``::

    parent run  "bench-<models>-<preset>"  (tag svbrdf.kind=bench; the report, tables and plots)
      child run  per model: the model's training run itself (svbrdf-train fit --parent-run), or,
                 for a reused run (--from-runs), a new run tagged svbrdf.train_run=<that run>
                 with that run's params; with ``--seeds N``, one per model and seed; with
                 several training budgets (``--minutes 2,8,32``, ``--steps``), the fit's run is
                 a child with no row of its own, and each budget a child tagged
                 svbrdf.train_run=<the fit>, scored from the fit's snapshot at that budget
      child run  per reference model (``--from-models FILE``, ``--models pretrained``): a model
                 file trained elsewhere on its own budget, tagged svbrdf.reference=<short name>,
                 its SHA-256 and source; params ``model.*`` and ``budget.*`` say what the file
                 records (steps, training time, device, hardware, data)
      child run  per baseline (``mean``, ``photo``; none with --no-baselines): a generator with
                 no trained parameters built from the registry, tagged svbrdf.baseline=true and
                 evaluated exactly like the models (same test images, same figures, params 0)
      child run  per row above and refinement budget N > 0 (``--refine 0,N,...``): that row's
                 maps refined for N steps against each test photo (svbrdf_render.refine_maps),
                 tagged svbrdf.refine_steps=N and svbrdf.refined_from=<the row's child run>,
                 label ``<row> +refine N``; it keeps the row's svbrdf.baseline and
                 svbrdf.reference tags (``mean +refine N`` is the pure-optimisation baseline:
                 refinement from constant maps). Budget 0 is the row itself, not a run of its own.

==================================  ======  ======================================================
name                                run     meaning
==================================  ======  ======================================================
tag ``svbrdf.kind``                 parent  ``bench``: the run is the parent of a benchmark
                                            (:data:`KIND_TAG`, :data:`BENCH_KIND`)
tag ``lpips``                       parent  how LPIPS was computed, or why it was not
                                            (:data:`LPIPS_TAG`)
params ``preset``, ``test_set``,    parent  the preset, the test set's description, the training
``train_minutes_per_model``,                budget per model in words, the real photos, the
``real_data``, ``baselines``,               baselines evaluated and the reference models'
``reference_models``                        sources with their SHA-256 prefixes ("-": none)
                                            (``*_PARAM``)
params ``refine_budgets``,          parent  the refinement budgets (``0``: none; absent in older
``refine_backend``,                         runs), the renderer backend and how the flash was
``refine_flash``                            found (:data:`REFINE_PARAM`, :data:`REFINE_BACKEND_PARAM`,
                                            :data:`REFINE_FLASH_PARAM`)
metrics ``phase/NN <name>``         parent  wall seconds of each phase of the run, in order (NN):
                                            checks and the test set, each training, each row's
                                            scoring; logged as each phase ends (:data:`PHASE_PREFIX`,
                                            :func:`phase_key`, :func:`read_phases`)
artifacts ``report/``               parent  the written report: ``report.md``, CSV, JSON, plots
                                            (:data:`REPORT_ARTIFACTS`)
artifact ``eval/test_groups.json``  parent  of a real test set: how samples were grouped
                                            (``des18``, ``file``), each sample's name and source
                                            materials, in order; the tables average per material.
                                            Absent (procedural, older runs): each image its own
                                            (:data:`TEST_GROUPS`, :func:`test_groups_json`,
                                            :func:`read_test_groups`; param ``group_by``)
tag ``mlflow.parentRunId``          child   the benchmark's parent run (MLflow's own nesting tag,
                                            :data:`PARENT_TAG`)
tag ``svbrdf.model``                child   the row label of the model or baseline; a child
                                            without it was trained but never evaluated
                                            (:data:`MODEL_TAG`)
tag ``svbrdf.train_run``            child   of a reused fit only: the run that trained it; without
                                            the tag the child is the fit itself
                                            (:data:`TRAIN_RUN_TAG`, :func:`train_run_id`)
tag ``svbrdf.baseline``             child   ``true``: an untrained baseline, not a trained model
                                            (:data:`BASELINE_TAG`, :func:`is_baseline`)
tag ``svbrdf.reference``            child   a reference model (a model file, not trained here nor
                                            at this benchmark's budget): its short name
                                            (:data:`REFERENCE_TAG`, :func:`reference_name`);
                                            tags ``svbrdf.model_sha256``, ``svbrdf.model_source``
params ``model.*``, ``budget.*``    child   of a reference model: the file's generator, source,
                                            SHA-256, and the budget its provenance records
                                            (:data:`BUDGET_PREFIX`)
artifact ``eval/per_sample.json``   child   each figure per test sample, ``{name: [values]}``
                                            (:data:`PER_SAMPLE`, :func:`per_sample_json`,
                                            :func:`read_per_sample`)
metrics ``test/<metric>/<map>``     child   the mean over the test images of a per-sample figure
                                            (:data:`TEST_PREFIX`)
metrics ``time/*``,                 child   training and inference time, parameters, peak memory
``model/params``, ``memory/*``              (the report's time table; :data:`STEPS_WALL_METRIC`)
metric ``train/steps``              child   generator steps the fit made (:data:`STEPS_METRIC`)
metrics ``real/*``                  child   self-consistency on real photos (no ground truth):
                                            per-sample ``real/rerender_rmse``, metric
                                            ``real/rerender_rmse_median`` (:data:`REAL_PREFIX`,
                                            :data:`REAL_RERENDER`)
tag ``svbrdf.refine_steps``         child   of a refined row: its budget N, the Adam steps of
                                            the refinement (:data:`REFINE_TAG`, :func:`refine_steps`)
tag ``svbrdf.refined_from``         child   of a refined row: the child run of the row it refined
                                            (:data:`REFINED_FROM_TAG`)
params ``refine.*``                 child   of a refined row: the budget, backend, flash and the
                                            :class:`svbrdf_render.RefineSettings` it ran with
metric ``refine/steps``             child   of a refined row: its budget; ``refine/steps_taken``
                                            the mean number of steps actually taken
metric ``time/seconds_per_image``   child   with ``--refine`` on (every row, budget 0 too): mean
                                            wall seconds per test image, one image at a time:
                                            network forward plus refinement (flash finding
                                            included); its parts ``time/network_seconds_per_image``
                                            and ``time/refine_seconds_per_image``
                                            (:data:`SECONDS_PER_IMAGE`)
per-sample ``photo/rerender_rmse``  child   with ``--refine`` on: RMSE of the maps re-rendered
                                            under the refinement's flash against the test photo
                                            (display encoding), logged as
                                            ``test/photo/rerender_rmse`` (:data:`INPUT_RERENDER`)
tag ``svbrdf.seed``                 child   of a fit's row (and of the fit's run): the seed of
                                            that fit, set as ``train.seed`` and ``data.seed``
                                            with ``--seeds N`` (:data:`SEED_TAG`)
tag ``svbrdf.method``               child   of a fit's row: the model it is a seed or budget of,
                                            its label without seed and budget (:data:`METHOD_TAG`)
tag ``svbrdf.budget``               child   of a fit's row: its training budget, ``8 min`` or
                                            ``500 steps`` (:data:`BUDGET_TAG`, :func:`budget_words`,
                                            :func:`read_budget`); absent: the recipe's schedule
                                            or a reused fit's own budget
tag ``svbrdf.snapshot``             child   of a row scored from a snapshot of its fit
                                            (``--minutes 2,8,32``): the snapshot's file,
                                            ``minutes-8.pt`` (:data:`SNAPSHOT_TAG`)
params ``seeds``, ``train_budgets`` parent  ``--seeds N`` and the training budgets, ``minutes 2,8,32``
                                            (:data:`SEEDS_PARAM`, :data:`BUDGETS_PARAM`)
param ``published_file``            parent  with ``--published FILE.yaml``: the file's name; the file
                                            itself, as written, is the artifact
                                            ``eval/published.yaml`` (:data:`PUBLISHED_PARAM`,
                                            :data:`PUBLISHED`; read by :mod:`svbrdf_bench.published`)
param ``test_resolution``           parent  the side in px the test images were scored at
                                            (:data:`TEST_RESOLUTION_PARAM`; absent in older runs)
artifact ``eval/missed_*.json``     parent  ``eval/missed_budgets.json``: the budgets a fit never
                                            reached, each ``{model, seed, budget, why}``
                                            (:data:`MISSED_BUDGETS`, :func:`read_missed`)
metrics ``val/*``, ``val_real/*``,  child   the trainer's own (learning curves,
``train/*``                                 :data:`FIT_WALL_METRIC`); never figures of the
                                            report's tables (:data:`TRAINER_PREFIXES`)
==================================  ======  ======================================================

Per-sample figures are named ``<metric>/<map>`` (``rmse/render``, ``ssim/normal``, ...) as
:func:`svbrdf_bench.metrics.evaluate` returns them, plus ``real/rerender_rmse``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import numpy as np

__all__ = [
    "KIND_TAG",
    "BENCH_KIND",
    "PARENT_TAG",
    "MODEL_TAG",
    "TRAIN_RUN_TAG",
    "BASELINE_TAG",
    "REFERENCE_TAG",
    "MODEL_SHA_TAG",
    "MODEL_SOURCE_TAG",
    "BUDGET_PREFIX",
    "LPIPS_TAG",
    "PRESET_PARAM",
    "TEST_SET_PARAM",
    "MINUTES_PARAM",
    "REAL_DATA_PARAM",
    "BASELINES_PARAM",
    "REFERENCES_PARAM",
    "PER_SAMPLE",
    "REPORT_ARTIFACTS",
    "TEST_PREFIX",
    "REAL_PREFIX",
    "REAL_RERENDER",
    "STEPS_METRIC",
    "STEPS_WALL_METRIC",
    "FIT_WALL_METRIC",
    "TRAINER_PREFIXES",
    "REFINE_TAG",
    "REFINED_FROM_TAG",
    "REFINE_PARAM",
    "REFINE_BACKEND_PARAM",
    "REFINE_FLASH_PARAM",
    "REFINE_STEPS_METRIC",
    "REFINE_TAKEN_METRIC",
    "SECONDS_PER_IMAGE",
    "NETWORK_SECONDS_PER_IMAGE",
    "REFINE_SECONDS_PER_IMAGE",
    "INPUT_RERENDER",
    "baseline_tags",
    "refine_steps",
    "is_baseline",
    "reference_name",
    "train_run_id",
    "per_sample_json",
    "read_per_sample",
    "TEST_GROUPS",
    "GROUP_BY_PARAM",
    "test_groups_json",
    "read_test_groups",
    "PHASE_PREFIX",
    "phase_key",
    "read_phases",
    "SEED_TAG",
    "METHOD_TAG",
    "BUDGET_TAG",
    "SNAPSHOT_TAG",
    "SEEDS_PARAM",
    "BUDGETS_PARAM",
    "MISSED_BUDGETS",
    "budget_words",
    "read_budget",
    "missed_json",
    "read_missed",
    "PUBLISHED",
    "PUBLISHED_PARAM",
    "TEST_RESOLUTION_PARAM",
]

#: Tag of the parent run; its value :data:`BENCH_KIND` marks a benchmark's parent.
KIND_TAG = "svbrdf.kind"
BENCH_KIND = "bench"
#: MLflow's tag that nests a child run under its parent.
PARENT_TAG = "mlflow.parentRunId"
#: Tag of an evaluated child run: its row label.
MODEL_TAG = "svbrdf.model"
#: Tag of the child run of a reused fit: the run that trained it.
TRAIN_RUN_TAG = "svbrdf.train_run"
#: Tag of the child runs of baselines (generators with no trained parameters): "true".
BASELINE_TAG = "svbrdf.baseline"
#: Tag of the child runs of reference models (model files trained elsewhere): their short name.
REFERENCE_TAG = "svbrdf.reference"
#: Tags of a reference model's child run: the SHA-256 of its file and where it was loaded from.
MODEL_SHA_TAG = "svbrdf.model_sha256"
MODEL_SOURCE_TAG = "svbrdf.model_source"
#: Params of a reference model's child run: the training budget its file records.
BUDGET_PREFIX = "budget."
#: Tag of the parent run: how LPIPS was computed (or why not).
LPIPS_TAG = "lpips"
#: Params of the parent run that the report shows.
PRESET_PARAM = "preset"
TEST_SET_PARAM = "test_set"
MINUTES_PARAM = "train_minutes_per_model"
REAL_DATA_PARAM = "real_data"
BASELINES_PARAM = "baselines"
REFERENCES_PARAM = "reference_models"
#: Artifact of each evaluated child run: every per-sample figure (:func:`per_sample_json`).
PER_SAMPLE = "eval/per_sample.json"
#: Artifact of the parent run of a real test set: each sample's name and source materials.
TEST_GROUPS = "eval/test_groups.json"
#: Param of the parent run: how the test samples were grouped into materials.
GROUP_BY_PARAM = "group_by"
#: Param of the parent run: the side in px the test images were scored at.
TEST_RESOLUTION_PARAM = "test_resolution"
#: Artifact of the parent run with ``--published FILE.yaml``: the file as written, and the param
#: that names it (:mod:`svbrdf_bench.published`).
PUBLISHED = "eval/published.yaml"
PUBLISHED_PARAM = "published_file"
#: Artifact folder of the parent run holding the written report.
REPORT_ARTIFACTS = "report"

#: Metrics of a child run that are means over the test images.
TEST_PREFIX = "test/"
#: Figures on real photos (no ground truth), kept out of the test means.
REAL_PREFIX = "real/"
#: Per-sample figure on real photos: RMSE of the maps re-rendered under the fitted flash.
REAL_RERENDER = "real/rerender_rmse"
#: Metric of an evaluated child run: the generator steps its fit made.
STEPS_METRIC = "train/steps"
#: Figure of a child run: wall seconds of the fit's steps (the trainer's :data:`FIT_WALL_METRIC`).
STEPS_WALL_METRIC = "time/train_steps_wall_s"
#: The trainer's metric of the wall seconds of its steps (absent from older fits).
FIT_WALL_METRIC = "train/total_wall_seconds"
#: Prefixes of the trainer's own metrics: never figures of the report's tables.
TRAINER_PREFIXES = ("val/", "val_real/", "train/")
#: Tags of a refined row's child run: its budget (Adam steps), and the child run of the row refined.
REFINE_TAG = "svbrdf.refine_steps"
REFINED_FROM_TAG = "svbrdf.refined_from"
#: Params of the parent run: the refinement budgets ("0,50,200"), backend and flash.
REFINE_PARAM = "refine_budgets"
REFINE_BACKEND_PARAM = "refine_backend"
REFINE_FLASH_PARAM = "refine_flash"
#: Metrics of a refined row's child run: its budget, and the mean steps taken per image.
REFINE_STEPS_METRIC = "refine/steps"
REFINE_TAKEN_METRIC = "refine/steps_taken"
#: Metrics with refinement on: mean wall seconds per test image (network + refinement), and its parts.
SECONDS_PER_IMAGE = "time/seconds_per_image"
NETWORK_SECONDS_PER_IMAGE = "time/network_seconds_per_image"
REFINE_SECONDS_PER_IMAGE = "time/refine_seconds_per_image"
#: Per-sample figure with refinement on: the maps re-rendered under the refinement's flash
#: against the test photo itself (RMSE, display encoding): what refinement optimises.
INPUT_RERENDER = "photo/rerender_rmse"


def baseline_tags(parent_id: str, name: str) -> dict[str, str]:
    """The tags of the child run of baseline ``name`` under ``parent_id``."""
    return {PARENT_TAG: parent_id, MODEL_TAG: name, BASELINE_TAG: "true"}


def is_baseline(tags: Mapping[str, str]) -> bool:
    """Whether a child run's tags mark an untrained baseline."""
    return tags.get(BASELINE_TAG) == "true"


def refine_steps(tags: Mapping[str, str]) -> int:
    """The refinement budget of a child run (see :data:`REFINE_TAG`); 0 for an unrefined row."""
    return int(tags.get(REFINE_TAG, 0) or 0)


def reference_name(tags: Mapping[str, str]) -> str | None:
    """The short name of a reference model's child run (see :data:`REFERENCE_TAG`); None for others."""
    return tags.get(REFERENCE_TAG) or None


def train_run_id(run_id: str, tags: Mapping[str, str]) -> str:
    """The run that trained the model of child run ``run_id``: the fit it reused, else itself."""
    return tags.get(TRAIN_RUN_TAG, run_id)


def per_sample_json(per_sample: Mapping[str, np.ndarray]) -> str:
    """The text of :data:`PER_SAMPLE`: figure name -> its value per test sample."""
    return json.dumps({k: v.tolist() for k, v in per_sample.items()})


def read_per_sample(text: str) -> dict[str, np.ndarray]:
    """Per-sample figures back from the text of :data:`PER_SAMPLE` (float64 arrays)."""
    return {k: np.asarray(v, dtype=np.float64) for k, v in json.loads(text).items()}


def test_groups_json(group_by: str, names: list[str], groups: list[tuple[str, ...]]) -> str:
    """The text of :data:`TEST_GROUPS`."""
    return json.dumps({"group_by": group_by, "names": list(names), "groups": [list(g) for g in groups]})


def read_test_groups(text: str) -> tuple[str, list[str], list[tuple[str, ...]]]:
    """``(group_by, names, groups)`` back from the text of :data:`TEST_GROUPS`."""
    doc = json.loads(text)
    return doc["group_by"], list(doc["names"]), [tuple(g) for g in doc["groups"]]


#: Metrics of the parent run: the wall seconds of each phase of the benchmark (see :func:`phase_key`).
PHASE_PREFIX = "phase/"


def phase_key(index: int, name: str) -> str:
    """The parent metric of the ``index``-th phase, ``name`` in words: ``phase/03 training ours``
    (characters MLflow refuses in a metric name become ``_``; the number keeps the order)."""
    safe = "".join(c if c.isalnum() or c in " -_./:" else "_" for c in name)
    return f"{PHASE_PREFIX}{index:02d} {safe}"


def read_phases(metrics: Mapping[str, float]) -> list[tuple[str, float]]:
    """``[(name, seconds)]`` in the order the phases ran, from a parent run's metrics."""
    keys = sorted(k for k in metrics if k.startswith(PHASE_PREFIX))
    return [(k[len(PHASE_PREFIX) :].split(" ", 1)[-1], float(metrics[k])) for k in keys]


#: Tags of a fit's row (and of the fit's own run): its seed (``train.seed`` and ``data.seed``), the
#: model it is a seed or budget of, its training budget (:func:`budget_words`), and the snapshot
#: of the fit it was scored from.
SEED_TAG = "svbrdf.seed"
METHOD_TAG = "svbrdf.method"
BUDGET_TAG = "svbrdf.budget"
SNAPSHOT_TAG = "svbrdf.snapshot"
#: Params of the parent run: ``--seeds N`` and the training budgets (``minutes 2,8,32``).
SEEDS_PARAM = "seeds"
BUDGETS_PARAM = "train_budgets"
#: Artifact of the parent run: the budgets a fit never reached (:func:`missed_json`).
MISSED_BUDGETS = "eval/missed_budgets.json"
#: The unit of each kind of training budget, as :data:`BUDGET_TAG` writes it.
_UNITS = {"minutes": "min", "steps": "steps"}


def budget_words(kind: str, mark: float) -> str:
    """The value of :data:`BUDGET_TAG`: ``8 min``, ``0.5 min``, ``500 steps``, ``1 step``."""
    unit = _UNITS[kind]
    return f"{mark:g} {unit[:-1] if unit == 'steps' and mark == 1 else unit}"


def read_budget(text: str | None) -> tuple[str, float] | None:
    """``(kind, mark)`` back from :func:`budget_words`' text; None for none or a text it did not write."""
    number, _, unit = (text or "").partition(" ")
    kind = next((k for k, u in _UNITS.items() if unit in (u, u.rstrip("s"))), None)
    try:
        return (kind, float(number)) if kind else None
    except ValueError:
        return None


def missed_json(missed: list[dict]) -> str:
    """The text of :data:`MISSED_BUDGETS`: ``[{model, seed, budget, why}]``."""
    return json.dumps(missed, indent=1)


def read_missed(text: str) -> list[dict]:
    """The budgets a fit never reached, back from the text of :data:`MISSED_BUDGETS`."""
    return list(json.loads(text))
