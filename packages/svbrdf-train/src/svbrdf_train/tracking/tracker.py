"""The run a fit logs to: :class:`Tracker` (records nothing) and :class:`MlflowTracker` (one
MLflow run), and what a fit's run records besides its params (:func:`log_fit_inputs`).

mlflow is imported only when a :class:`MlflowTracker` is made (``import mlflow`` takes ~2 s
and pulls ~850 MB of packages the networks and the renderer never need).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from svbrdf_render.plumbing import atomic_output

from ..errors import CheckpointError, TrackingError
from .datasets import fit_datasets, log_datasets
from .store import experiment_id, open_client, quiet_store_logs, store_error
from .system_metrics import system_metrics_monitor
from .ui import save_runs_view, ui_hint

__all__ = ["Tracker", "MlflowTracker", "flatten_params", "log_fit_inputs", "FIT_VIEW", "FIT_VIEW_NAME",
           "FIT_COLUMNS"]  # fmt: skip


class Tracker:
    """The interface the trainer logs through; this base class records nothing (ranks > 0)."""

    run_id: str | None = None

    def log_metrics(self, metrics: Mapping[str, float], step: int) -> None:
        pass

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        pass

    def log_image(self, path: str | Path, key: str, step: int) -> None:
        pass

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        pass

    def finish(self, status: str) -> None:
        pass

    def describe(self) -> str:
        return "not tracked"


def flatten_params(config: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested config -> ``{"loss.adv": "0.1", ...}``, the form MLflow params take."""
    out: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.update(flatten_params(value, f"{name}."))
        else:
            out[name] = str(value)
    return out


class MlflowTracker(Tracker):
    """One MLflow run: a new one, or ``run_id`` continued (after ``--resume``).

    Args:
        experiment: experiment name (made if missing, with its artifacts beside a local store and
            the kind tag of a model-training experiment).
        run_name: shown in the UI.
        tags, params: set on a new run (params are immutable in MLflow, so a continued run
            keeps the ones it has).
        run_id: continue this run instead of making one; it must exist in the store.

    With :data:`.system_metrics.SYSTEM_METRICS_ENV` on (``--system-metrics``), MLflow's system
    metrics are sampled into the run until :meth:`finish`.
    """

    _monitor = None  # MLflow's system-metrics thread, when SYSTEM_METRICS_ENV is on

    def __init__(
        self,
        *,
        experiment: str,
        run_name: str | None = None,
        tags: Mapping[str, str] | None = None,
        params: Mapping[str, str] | None = None,
        run_id: str | None = None,
    ):
        import mlflow
        from mlflow.entities import Param

        self.uri = mlflow.get_tracking_uri()
        try:
            with quiet_store_logs():
                self.client = open_client(self.uri)
        except TrackingError:  # already one line naming the store
            raise
        except Exception as e:  # database, connection and permission errors alike
            raise store_error("open the MLflow store", self.uri, e) from None
        if run_id is not None:
            try:
                run = self.client.get_run(run_id)
            except Exception as e:  # MlflowException, or a connection error for a server
                raise CheckpointError(
                    f"the checkpoint continues MLflow run {run_id}, which the store {self.uri} does not "
                    f"have ({type(e).__name__}); point MLFLOW_TRACKING_URI at the store of the first run"
                ) from None
            self.run_id = run.info.run_id
            self.experiment_id = run.info.experiment_id
            self.client.update_run(self.run_id, status="RUNNING")
            if tags:
                self.set_tags(tags)
            self._monitor = system_metrics_monitor(self.run_id, self.uri, resume=True)
            return
        try:
            with quiet_store_logs():
                self.experiment_id = self._experiment(experiment)
                run = self.client.create_run(self.experiment_id, run_name=run_name, tags=dict(tags or {}))
        except Exception as e:  # MlflowException, connection and database errors alike
            raise store_error("start a run in the MLflow store", self.uri, e) from None
        self.run_id = run.info.run_id
        items = list((params or {}).items())
        for start in range(0, len(items), 100):  # MLflow takes at most 100 params per batch
            chunk = items[start : start + 100]
            self.client.log_batch(self.run_id, params=[Param(k, v) for k, v in chunk])
        self._monitor = system_metrics_monitor(self.run_id, self.uri, resume=False)

    def _experiment(self, name: str) -> str:
        return experiment_id(self.client, self.uri, name)

    def log_metrics(self, metrics: Mapping[str, float], step: int) -> None:
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, int(step)) for k, v in metrics.items()]
        with self._writing("log metrics to"):
            for start in range(0, len(items), 1000):
                self.client.log_batch(self.run_id, metrics=items[start : start + 1000])

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Copy a file into the run's artifacts.

        Into a local store the copy is atomic (:func:`svbrdf_render.plumbing.atomic_output`): a full
        disk keeps the previous artifact of that name (the last good checkpoint) and leaves no
        partial file. A server's store goes through MLflow's client.
        """
        folder = self._artifact_folder()
        if folder is not None:
            with atomic_output(folder / (artifact_path or "") / Path(path).name) as tmp:
                shutil.copyfile(path, tmp)
            return
        with self._writing(f"log {Path(path).name} to"):
            self.client.log_artifact(self.run_id, os.fspath(path), artifact_path)

    def _artifact_folder(self) -> Path | None:
        """The run's artifact folder when it is on this machine's file system, else None."""
        if not hasattr(self, "_artifacts"):
            uri = self.client.get_run(self.run_id).info.artifact_uri
            parsed = urlparse(uri)
            self._artifacts = Path(unquote(parsed.path)) if parsed.scheme in ("", "file") else None
        return self._artifacts

    def log_image(self, path: str | Path, key: str, step: int) -> None:
        """The image file ``path`` as step ``step`` of the image series ``key``: the UI shows the
        series with a step slider (unlike a plain artifact)."""
        from PIL import Image

        with Image.open(path) as image, self._writing(f"log image {key} of step {step} to"):
            image.load()
            self.client.log_image(self.run_id, image, key=key, step=int(step))

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        from mlflow.entities import RunTag

        with self._writing("set tags in"):
            self.client.log_batch(self.run_id, tags=[RunTag(k, str(v)) for k, v in tags.items()])

    def finish(self, status: str) -> None:
        if self._monitor is not None:  # its last sample first, while the run is open
            with contextlib.suppress(Exception):
                self._monitor.finish()
            self._monitor = None
        with self._writing(f"mark the run {status} in"):
            self.client.set_terminated(self.run_id, status)

    @contextlib.contextmanager
    def _writing(self, what: str):
        """Store errors while the run is logged: one line (TrackingError), no MLflow traceback."""
        try:
            with quiet_store_logs():
                yield
        except Exception as e:
            raise store_error(what, self.uri, e) from None

    def describe(self) -> str:
        """Which run, in which store, and the UI's address of its page."""
        return f"MLflow run {self.run_id} in {ui_hint(self.uri, self.experiment_id, self.run_id)}"

    def log_datasets(self, datasets: Sequence[tuple[Any, str]]) -> None:
        """``(dataset, context)`` pairs (:func:`.datasets.test_dataset`,
        :func:`.datasets.fit_datasets`) as the run's dataset inputs."""
        with self._writing("log the datasets to"):
            log_datasets(self.client, self.run_id, datasets)

    def save_runs_view(self, key: str, name: str, **state: Any) -> str:
        """:func:`save_runs_view` in this run's experiment; returns the view's key."""
        with self._writing("save a view of the runs in"):
            save_runs_view(self.client, self.experiment_id, key, name, **state)
        return key


#: The saved view of a fit experiment's runs: the last validation RMSE per map, throughput, time.
FIT_VIEW = "svbrdf-fits"
FIT_VIEW_NAME = "svbrdf: fits (last validation)"
FIT_COLUMNS = (
    "val/rmse/render", "val/rmse/normal", "val/rmse/diffuse", "val/rmse/roughness", "val/rmse/specular",
    "train/steady_samples_per_s", "train/total_seconds",
)  # fmt: skip


def log_fit_inputs(tracker: Tracker, recipe, *, parent_run: str | None = None) -> None:
    """What a fit's MLflow run records besides its params: its data as dataset inputs
    (:func:`fit_datasets`), and, for a fit of its own (no ``parent_run``), the saved view
    :data:`FIT_VIEW` of its experiment's runs with the validation figures as columns, which
    :meth:`MlflowTracker.describe` and ``ui_page(..., view=FIT_VIEW)`` open."""
    if not isinstance(tracker, MlflowTracker):
        return
    tracker.log_datasets(fit_datasets(recipe))
    if parent_run is None:
        tracker.save_runs_view(FIT_VIEW, FIT_VIEW_NAME, columns=FIT_COLUMNS, column_width=140)
