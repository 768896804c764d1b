"""MLflow tracking of a fit: one run, its params, tags, metrics and artifacts.

mlflow is imported only when a :class:`MlflowTracker` is made (``import mlflow`` takes ~2 s
and pulls ~850 MB of packages the networks and the renderer never need).

Where runs go is MLflow's choice: ``MLFLOW_TRACKING_URI`` when set (a folder, a sqlite file or
an ``http://`` server), else MLflow's default (``sqlite:///mlflow.db`` in the working folder).
For a local store this module sets the experiment's artifact folder explicitly, beside the
store (``mlartifacts/`` next to ``mlflow.db``), so artifacts never land somewhere that depends
on the folder a later command runs in. A server keeps its own artifact root.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import shutil
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import torch

from svbrdf_render.errors import OutputError
from svbrdf_render.files import atomic_output

from .errors import CheckpointError, TrackingError

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
    "experiment_id",
]

#: The distributions whose versions every run records.
PACKAGES = ("svbrdf-render", "svbrdf-models", "svbrdf-train", "torch", "numpy", "mlflow")
#: MLflow 3 keeps an experiment's kind in this tag; the UI opens the model-training view for this
#: value rather than the GenAI one. Set on every experiment this project creates.
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"


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


def tracking_uri() -> str:
    """The store runs go to: ``MLFLOW_TRACKING_URI``, else MLflow's default."""
    import mlflow

    return mlflow.get_tracking_uri()


def _local_store_folder(uri: str) -> Path | None:
    """The folder of a local store (sqlite file or file store), None for a server."""
    parsed = urlparse(uri)
    if parsed.scheme == "sqlite":
        # sqlite:///relative.db has the path "/relative.db", sqlite:////abs.db "//abs.db"
        return Path(unquote(parsed.path)[1:]).resolve().parent
    if parsed.scheme in ("", "file"):
        return Path(unquote(parsed.path) or uri).resolve()
    return None


@contextlib.contextmanager
def _store_lock(uri: str):
    """An exclusive lock on ``<store>.lock`` beside a SQLite store, for its first use by a process.

    MLflow creates and migrates a SQLite store's tables on first open, without a lock: two fits
    started together on a new store race, and the loser dies (``table experiment_tags already
    exists``) or leaves the store unopenable. Other stores need no lock (a server serialises).
    """
    parsed = urlparse(uri)
    if parsed.scheme != "sqlite":
        yield
        return
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock (the race needs two first uses at the same instant)
        yield
        return
    db = Path(unquote(parsed.path)[1:]).resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    with open(db.with_name(db.name + ".lock"), "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _root_cause(error: BaseException) -> BaseException:
    """The exception at the bottom of a chain (MLflow wraps SQLAlchemy, which wraps sqlite3)."""
    seen = {id(error)}
    while True:
        inner = error.__cause__ or error.__context__
        if inner is None or id(inner) in seen:
            return error
        seen.add(id(inner))
        error = inner


def _store_error(what: str, uri: str, error: Exception) -> TrackingError:
    """One line: what could not be done with the store, the root cause's first line, what to do."""
    cause = _root_cause(error)
    text = str(cause).strip()
    first = text.splitlines()[0][:200] if text else ""
    lowered = f"{type(cause).__name__} {text}".lower()
    refused = True  # the store's disk refused a write: exit status 3, like any failed write
    if "readonly" in lowered or "read-only" in lowered or "permission" in lowered:
        hint = "the store cannot be written: point MLFLOW_TRACKING_URI at a writable store"
    elif ("disk" in lowered and "full" in lowered) or "no space" in lowered:
        hint = "its disk is full: free some space or point MLFLOW_TRACKING_URI elsewhere"
    else:
        refused = False
        remote = urlparse(uri).scheme in ("http", "https")
        hint = "start the server or fix MLFLOW_TRACKING_URI" if remote else "fix MLFLOW_TRACKING_URI"
    error = TrackingError(
        f"cannot {what} {uri} ({type(cause).__name__}: {first}); {hint}, "
        "or pass --no-track to train without MLflow"
    )
    if refused:
        error.exit_code = OutputError.exit_code
    return error


@contextlib.contextmanager
def quiet_store_logs():
    """Silence MLflow's database logger: it logs an error with its traceback before raising it
    (the caller words it) and a new store's table creation at INFO level."""
    import logging

    logger = logging.getLogger("mlflow.store.db.utils")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def open_client(uri: str):
    """An MlflowClient on ``uri`` whose store is created (tables and all) by one process at a time."""
    from mlflow import MlflowClient

    with _store_lock(uri), quiet_store_logs():
        client = MlflowClient(uri)
        client.search_experiments(max_results=1)  # opens the store: creates or migrates its tables
    return client


def experiment_id(client, uri: str, name: str) -> str:
    """The id of experiment ``name`` in the store at ``uri``, made if missing: its artifacts
    beside a local store, tagged as a model-training experiment."""
    found = client.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    folder = _local_store_folder(uri)
    location = None
    if folder is not None:
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
        location = (folder / "mlartifacts" / safe).as_uri()
    try:
        return client.create_experiment(
            name, artifact_location=location, tags={EXPERIMENT_KIND_TAG: EXPERIMENT_KIND}
        )
    except Exception:  # made by another process in the meantime
        found = client.get_experiment_by_name(name)
        if found is None:
            raise
        return found.experiment_id


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


def git_revision(folder: str | Path | None = None) -> tuple[str, bool]:
    """``(sha, dirty)`` of the git checkout holding ``folder`` (this package by default);
    ``("unknown", False)`` for an installed wheel or without git."""
    folder = Path(folder or Path(__file__).parent)
    try:
        sha = subprocess.run(
            ["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if sha.returncode != 0:
            return "unknown", False
        status = subprocess.run(
            ["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        return sha.stdout.strip(), bool(status.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "unknown", False


def hardware(device: str | torch.device) -> str:
    """The machine a fit ran on, in words: the GPU's name, or the CPU's model and core count."""
    device = torch.device(device)
    if device.type == "cuda":
        return f"{torch.cuda.device_count()} x {torch.cuda.get_device_name(device)}"
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    threads = torch.get_num_threads()
    return f"{os.cpu_count()} cores of {name}, torch on {threads} thread{'s' if threads > 1 else ''}"


def made_with(device: str | torch.device) -> dict[str, str]:
    """What a checkpoint records about how it was made: code revision, versions, machine."""
    sha, dirty = git_revision()
    return {
        "git_sha": sha,
        "git_dirty": str(dirty).lower(),
        "torch": str(torch.__version__),
        "svbrdf_train": importlib.metadata.version("svbrdf-train"),
        "device": str(device),
        "hardware": hardware(device),
    }


def run_tags(*, recipe: str, size: str, seed: int, device: str, world_size: int) -> dict[str, str]:
    """What identifies how a run was made: code, versions, machine, seed, recipe."""
    sha, dirty = git_revision()
    tags = {
        "recipe": recipe,
        "recipe.size": size,
        "seed": str(seed),
        "device": device,
        "world_size": str(world_size),
        "git_sha": sha,
        "git_dirty": str(dirty).lower(),
        "mlflow.source.git.commit": sha,
        "host": platform.node(),
        "python": platform.python_version(),
    }
    for dist in PACKAGES:
        try:
            tags[f"version.{dist}"] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            tags[f"version.{dist}"] = "not installed"
    return tags


class MlflowTracker(Tracker):
    """One MLflow run: a new one, or ``run_id`` continued (after ``--resume``).

    Args:
        experiment: experiment name (made if missing, with its artifacts beside a local store and
            the kind tag of a model-training experiment).
        run_name: shown in the UI.
        tags, params: set on a new run (params are immutable in MLflow, so a continued run
            keeps the ones it has).
        run_id: continue this run instead of making one; it must exist in the store.
    """

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
        except Exception as e:  # database, connection and permission errors alike
            raise _store_error("open the MLflow store", self.uri, e) from None
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
            return
        try:
            with quiet_store_logs():
                self.experiment_id = self._experiment(experiment)
                run = self.client.create_run(self.experiment_id, run_name=run_name, tags=dict(tags or {}))
        except Exception as e:  # MlflowException, connection and database errors alike
            raise _store_error("start a run in the MLflow store", self.uri, e) from None
        self.run_id = run.info.run_id
        items = list((params or {}).items())
        for start in range(0, len(items), 100):  # MLflow takes at most 100 params per batch
            chunk = items[start : start + 100]
            self.client.log_batch(self.run_id, params=[Param(k, v) for k, v in chunk])

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

        Into a local store the copy is atomic (:func:`svbrdf_render.files.atomic_output`): a full
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
        with self._writing(f"mark the run {status} in"):
            self.client.set_terminated(self.run_id, status)

    @contextlib.contextmanager
    def _writing(self, what: str):
        """Store errors while the run is logged: one line (TrackingError), no MLflow traceback."""
        try:
            with quiet_store_logs():
                yield
        except Exception as e:
            raise _store_error(what, self.uri, e) from None

    def describe(self) -> str:
        where = self.uri
        if where.startswith("sqlite:"):
            where = f"{where}  (see it: mlflow ui --backend-store-uri {where})"
        return f"MLflow run {self.run_id} in {where}"
