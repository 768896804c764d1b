"""MLflow tracking of a fit: one run, its params, tags, metrics, artifacts and data.

mlflow is imported only when a run is made or a store is opened (``import mlflow`` takes ~2 s
and pulls ~850 MB of packages the networks and the renderer never need).

=================  ===========================================================================
module             holds
=================  ===========================================================================
store              which store runs go to (``MLFLOW_TRACKING_URI``, else MLflow's default), its
                   checks before use, opening it, its experiments, its errors in one line
tracker            the run a fit logs to (:class:`Tracker`, :class:`MlflowTracker`), its params
                   and what a fit records besides them (:func:`log_fit_inputs`)
provenance         where a run comes from: git revision, versions, machine, command (tags)
datasets           a run's data as MLflow dataset inputs, described, not stored
ui                 the UI's addresses (model-training pages) and saved views of a runs page
system_metrics     MLflow's ``system/...`` metrics, on with ``--system-metrics``
=================  ===========================================================================

Every public name of these modules is importable from here.
"""

from __future__ import annotations

from .datasets import CONTENT_DIGEST_LIMIT, files_digest, fit_datasets, log_datasets, test_dataset
from .provenance import PACKAGES, git_revision, hardware, made_with, run_tags, source_tags
from .store import (
    EXPERIMENT_KIND,
    EXPERIMENT_KIND_TAG,
    MLFLOW_TABLES,
    OPEN_TIMEOUT_S,
    check_store,
    experiment_id,
    local_store_folder,
    open_client,
    quiet_store_logs,
    store_error,
    tracking_uri,
)
from .store import _store_lock as _store_lock  # the lock's own test takes it from here
from .system_metrics import SYSTEM_METRICS_ENV, enable_system_metrics, system_metrics_monitor
from .tracker import (
    FIT_COLUMNS,
    FIT_VIEW,
    FIT_VIEW_NAME,
    MlflowTracker,
    Tracker,
    flatten_params,
    log_fit_inputs,
)
from .ui import LOCAL_UI, VIEW_TAG_PREFIX, WORKFLOW_QUERY, save_runs_view, ui_hint, ui_page, ui_url

__all__ = [
    "Tracker",
    "MlflowTracker",
    "flatten_params",
    "run_tags",
    "tracking_uri",
    "git_revision",
    "made_with",
    "hardware",
    "quiet_store_logs",
    "open_client",
    "check_store",
    "experiment_id",
    "source_tags",
    "ui_url",
    "ui_page",
    "ui_hint",
    "save_runs_view",
    "files_digest",
    "test_dataset",
    "fit_datasets",
    "log_datasets",
    "log_fit_inputs",
    "enable_system_metrics",
    # constants, and helpers the modules share
    "PACKAGES",
    "EXPERIMENT_KIND_TAG",
    "EXPERIMENT_KIND",
    "WORKFLOW_QUERY",
    "LOCAL_UI",
    "VIEW_TAG_PREFIX",
    "SYSTEM_METRICS_ENV",
    "CONTENT_DIGEST_LIMIT",
    "OPEN_TIMEOUT_S",
    "MLFLOW_TABLES",
    "FIT_VIEW",
    "FIT_VIEW_NAME",
    "FIT_COLUMNS",
    "local_store_folder",
    "store_error",
    "system_metrics_monitor",
]
