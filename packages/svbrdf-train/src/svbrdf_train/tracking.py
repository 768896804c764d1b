"""MLflow tracking of a fit: one run, its params, tags, metrics and artifacts.

mlflow is imported only when a :class:`MlflowTracker` is made (``import mlflow`` takes ~2 s
and pulls ~850 MB of packages the networks and the renderer never need).

Where runs go is MLflow's choice: ``MLFLOW_TRACKING_URI`` when set (a folder, a sqlite file or
an ``http://`` server), else MLflow's default (``sqlite:///mlflow.db`` in the working folder).
For a local store this module sets the experiment's artifact folder explicitly, beside the
store (``mlartifacts/`` next to ``mlflow.db``), so artifacts never land somewhere that depends
on the folder a later command runs in. A server keeps its own artifact root.

What the UI shows: every address this module gives opens MLflow 3's model-training pages
(:data:`WORKFLOW_QUERY`, :func:`ui_page`); a saved view of an experiment's runs page picks its
columns (:func:`save_runs_view`); runs record their data as MLflow datasets, described, not
stored (:func:`test_dataset`, :func:`fit_datasets`), and where they come from (:func:`source_tags`);
MLflow's system metrics are on with ``--system-metrics`` (:func:`enable_system_metrics`).
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import shutil
import subprocess
import time
from collections.abc import Mapping, Sequence
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
]

#: The distributions whose versions every run records.
PACKAGES = ("svbrdf-render", "svbrdf-models", "svbrdf-train", "torch", "numpy", "mlflow")
#: MLflow 3 keeps an experiment's kind in this tag, set on every experiment this project creates or
#: logs to; MLflow 3 UIs before workflow-based navigation chose an experiment's pages by it. MLflow
#: 3.17's UI does not read it: see :data:`WORKFLOW_QUERY`.
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"
#: The query parameter of a UI address that makes MLflow 3.17's UI open an experiment on its runs.
#: That UI (its bundle, ``mlflow/server/js/build/static/js/main.*.js``) takes an experiment's kind
#: from the *workflow type* whenever workflow-based navigation is on, which 3.17 hard-codes, and
#: never reads :data:`EXPERIMENT_KIND_TAG`; the workflow type is the address's ``workflowType``
#: parameter, else the browser's remembered choice (local storage ``mlflow.workflowType_v1``, set
#: by the "GenAI / Model training" switch at the top of the side bar), else ``genai``. So a fresh
#: browser opens every experiment on its GenAI overview ("Traces 0") unless the address says
#: otherwise: every address this module gives carries this parameter.
WORKFLOW_QUERY = "workflowType=machine_learning"
#: Where ``mlflow ui`` serves by default: the addresses given for a local store start here.
LOCAL_UI = "http://127.0.0.1:5000"
#: An experiment tag ``<prefix><key>`` holds a saved view of its runs page (columns, filter,
#: grouping): the UI lists it under "Views" and opens it for ``?viewStateShareKey=<key>``.
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
#: MLflow's own switch for system metrics (CPU, memory, disk, network, GPU every 10 s, as
#: ``system/...`` metrics); ``--system-metrics`` sets it, and child processes inherit it.
SYSTEM_METRICS_ENV = "MLFLOW_ENABLE_SYSTEM_METRICS_LOGGING"
#: A dataset's files are hashed byte by byte up to this total size; above it, by names and sizes.
CONTENT_DIGEST_LIMIT = 1 << 30


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
    The lock is ``filelock``'s: ``flock`` on POSIX (the lock file stays, so every process locks
    the same file, and a process of an earlier version, which took the same ``flock`` by hand,
    is still excluded), the system's own file lock on Windows.
    """
    parsed = urlparse(uri)
    if parsed.scheme != "sqlite":
        yield
        return
    from filelock import FileLock

    db = Path(unquote(parsed.path)[1:]).resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(db.with_name(db.name + ".lock")):
        yield


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


#: How long the first request to a tracking server may take before the command gives up (and the
#: connection probe before it), unless ``MLFLOW_HTTP_REQUEST_TIMEOUT`` says otherwise; MLflow's own
#: default (120 s, retried 7 times with back-off: over 4 minutes) leaves a user staring at nothing.
OPEN_TIMEOUT_S = 10
#: Tables every MLflow SQL store has: an existing SQLite file without them is not an MLflow store.
MLFLOW_TABLES = frozenset({"experiments", "runs", "alembic_version"})


def _env_number(name: str, default: float) -> float:
    try:
        return float(os.environ[name])
    except (KeyError, ValueError):
        return default


def check_store(uri: str) -> None:
    """Refuse, before anything is written, a store MLflow would hang on or damage
    (:class:`TrackingError`, one line naming ``uri`` and what to do):

    - a SQLite URI naming a folder, or an existing file that is not an MLflow store (an empty
      file, another program's database, not a database): MLflow would write its ~65 tables
      into it (a new path is fine, and so is an existing MLflow store);
    - a server nothing answers at: the connection is tried once, for ``MLFLOW_HTTP_REQUEST_TIMEOUT``
      seconds (:data:`OPEN_TIMEOUT_S` when unset), instead of MLflow's minutes of retries.
    """
    parsed = urlparse(uri)
    if parsed.scheme == "sqlite":
        _check_sqlite(uri, Path(unquote(parsed.path)[1:]))
    elif parsed.scheme in ("http", "https"):
        import socket

        timeout = _env_number("MLFLOW_HTTP_REQUEST_TIMEOUT", OPEN_TIMEOUT_S)
        port = parsed.port or (443 if parsed.scheme == "https" else 80)
        try:
            socket.create_connection((parsed.hostname or "localhost", port), timeout=timeout).close()
        except OSError as e:
            reason = "no answer" if isinstance(e, TimeoutError) else (e.strerror or type(e).__name__)
            raise TrackingError(
                f"cannot reach the MLflow server {uri} ({reason}; connection timeout {timeout:g} s, "
                "MLFLOW_HTTP_REQUEST_TIMEOUT); start the server or fix MLFLOW_TRACKING_URI, "
                "or pass --no-track to train without MLflow"
            ) from None


def _check_sqlite(uri: str, db: Path) -> None:
    """See :func:`check_store`: the SQLite file must be new or an MLflow store."""
    import sqlite3

    what = None
    if db.is_dir():
        what = "is a folder, not a SQLite file"
    elif db.exists():
        if db.stat().st_size == 0:
            what = "is an empty file, not an MLflow store"
        else:
            try:
                con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True, timeout=30)
                try:
                    rows = con.execute("SELECT name FROM sqlite_master WHERE type='table'")
                    tables = {row[0] for row in rows}
                finally:
                    con.close()
            except sqlite3.Error as e:
                what = f"is not a SQLite database ({e})"
            else:
                if not MLFLOW_TABLES <= tables:
                    what = f"is a SQLite database of another program ({len(tables)} tables, not MLflow's)"
    if what:
        raise TrackingError(
            f"MLFLOW_TRACKING_URI {uri}: {db} {what}; point MLFLOW_TRACKING_URI at a new file or an "
            "existing MLflow store (MLflow would write its tables into any other file), or pass --no-track"
        )


@contextlib.contextmanager
def _first_request_bounded():
    """MLflow's HTTP timeout and retries bounded for the first request (unless the user set
    them): a server that accepts connections and never answers is given up on in
    :data:`OPEN_TIMEOUT_S`, not after 7 retries of 120 s each."""
    bounds = {"MLFLOW_HTTP_REQUEST_TIMEOUT": str(OPEN_TIMEOUT_S), "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0"}
    added = {k: v for k, v in bounds.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


def open_client(uri: str):
    """An MlflowClient on ``uri`` whose store is created (tables and all) by one process at a time.

    The store is checked first (:func:`check_store`): a file that is not an MLflow store is
    refused before anything is written, and a server that does not answer within
    ``MLFLOW_HTTP_REQUEST_TIMEOUT`` (:data:`OPEN_TIMEOUT_S` when unset) is one
    :class:`TrackingError`, not minutes of silence.
    """
    from mlflow import MlflowClient

    check_store(uri)
    remote = urlparse(uri).scheme in ("http", "https")
    bounded = _first_request_bounded() if remote else contextlib.nullcontext()
    with _store_lock(uri), quiet_store_logs(), bounded:
        client = MlflowClient(uri)
        try:
            client.search_experiments(max_results=1)  # opens the store: creates or migrates its tables
        except Exception as e:
            if not remote:
                raise
            cause = _root_cause(e)
            raise TrackingError(
                f"the MLflow server {uri} did not answer ({type(cause).__name__}; timeout "
                f"{_env_number('MLFLOW_HTTP_REQUEST_TIMEOUT', OPEN_TIMEOUT_S):g} s, "
                "MLFLOW_HTTP_REQUEST_TIMEOUT and MLFLOW_HTTP_REQUEST_MAX_RETRIES); start the server or fix "
                "MLFLOW_TRACKING_URI, or pass --no-track to train without MLflow"
            ) from None
    return client


def experiment_id(client, uri: str, name: str) -> str:
    """The id of experiment ``name`` in the store at ``uri``, made if missing: its artifacts
    beside a local store, tagged as a model-training experiment (an existing one without the tag
    gets it)."""
    found = client.get_experiment_by_name(name)
    if found is not None:
        if EXPERIMENT_KIND_TAG not in found.tags:
            client.set_experiment_tag(found.experiment_id, EXPERIMENT_KIND_TAG, EXPERIMENT_KIND)
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


def source_tags(command: str, sha: str | None = None) -> dict[str, str]:
    """MLflow's tags for where a run comes from, which its UI shows as the run's Source and
    "Created by": the command (``svbrdf-train fit``), of type LOCAL, at git commit ``sha`` (this
    checkout's by default; none for an installed wheel), and the user."""
    import getpass

    if sha is None:
        sha, _ = git_revision()
    tags = {"mlflow.source.name": command, "mlflow.source.type": "LOCAL"}
    if sha != "unknown":
        tags["mlflow.source.git.commit"] = sha
    with contextlib.suppress(Exception):  # no user name in some containers
        tags["mlflow.user"] = getpass.getuser()
    return tags


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
        **source_tags("svbrdf-train fit", sha),
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

    With :data:`SYSTEM_METRICS_ENV` on (``--system-metrics``), MLflow's system metrics are sampled
    into the run until :meth:`finish`.
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
            self._monitor = _system_metrics_monitor(self.run_id, self.uri, resume=True)
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
        self._monitor = _system_metrics_monitor(self.run_id, self.uri, resume=False)

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
            raise _store_error(what, self.uri, e) from None

    def describe(self) -> str:
        """Which run, in which store, and the UI's address of its page."""
        return f"MLflow run {self.run_id} in {ui_hint(self.uri, self.experiment_id, self.run_id)}"

    def log_datasets(self, datasets: Sequence[tuple[Any, str]]) -> None:
        """``(dataset, context)`` pairs (:func:`test_dataset`, :func:`fit_datasets`) as the run's
        dataset inputs."""
        with self._writing("log the datasets to"):
            log_datasets(self.client, self.run_id, datasets)

    def save_runs_view(self, key: str, name: str, **state: Any) -> str:
        """:func:`save_runs_view` in this run's experiment; returns the view's key."""
        with self._writing("save a view of the runs in"):
            save_runs_view(self.client, self.experiment_id, key, name, **state)
        return key


# -- what the UI opens on -------------------------------------------------------------------------


def ui_page(
    experiment_id: str, run_id: str | None = None, *, view: str | None = None, artifact: str | None = None
) -> str:
    """The UI's address of a page, relative to the UI (``#/experiments/E/runs?...``): the runs
    page of experiment ``experiment_id`` (in the saved ``view``, see :func:`save_runs_view`), or
    run ``run_id``'s page (its file ``artifact`` shown); always with :data:`WORKFLOW_QUERY`, so
    that MLflow 3.17's UI opens it as a model-training page."""
    from urllib.parse import quote, urlencode

    path = f"#/experiments/{experiment_id}/runs"
    if run_id is not None:
        path += f"/{run_id}"
        if artifact:
            path += f"/artifacts/{quote(artifact)}"
    query = WORKFLOW_QUERY
    if view is not None and run_id is None:
        query += "&" + urlencode({"viewStateShareKey": view})
    return f"{path}?{query}"


def ui_url(uri: str, experiment_id: str, run_id: str | None = None, **page: str | None) -> str | None:
    """The whole address of :func:`ui_page` for the store ``uri``: on the server itself for an
    ``http(s)://`` store, on ``mlflow ui``'s default address (:data:`LOCAL_UI`) for a local one;
    None for a store of another kind (its UI's address is not known here)."""
    parsed = urlparse(uri)
    if parsed.scheme in ("http", "https"):
        base = uri.rstrip("/")
    elif _local_store_folder(uri) is not None:
        base = LOCAL_UI
    else:
        return None
    return f"{base}/{ui_page(experiment_id, run_id, **page)}"


def ui_hint(uri: str, experiment_id: str, run_id: str | None = None, **page: str | None) -> str:
    """``uri``, and how to see a page of it (:func:`ui_page`) in the UI: for a local store, the
    command that serves it and the address; for a server, the address."""
    url = ui_url(uri, experiment_id, run_id, **page)  # last on the line: nothing sticks to it
    if url is None:
        return uri
    if uri.startswith(("http://", "https://")):
        return f"{uri}; see it at {url}"
    return f"{uri}; see it with `mlflow ui --backend-store-uri {uri}`, then {url}"


def save_runs_view(
    client,
    experiment_id: str,
    key: str,
    name: str,
    *,
    columns: Sequence[str] = (),
    search: str = "",
    group_by_tag: str | None = None,
    column_width: int | None = None,
) -> None:
    """Save a view of experiment ``experiment_id``'s runs page under ``key`` (made or replaced):
    the UI lists it as ``name`` under "Views", and :func:`ui_page` with ``view=key`` opens it.

    Args:
        columns: metric names shown as columns, in order (the runs page shows none by default).
        search: the runs filter, in MLflow's search syntax.
        group_by_tag: runs grouped by this tag's value, every group open (child runs are hidden
            under their parent otherwise, and a view cannot open a parent).
        column_width: width in pixels of the metric columns.

    The view is an experiment tag (:data:`VIEW_TAG_PREFIX` + ``key``) holding
    ``{"name", "createdAt", "updatedAt", "state"}``, ``state`` the JSON of the page's settings,
    as the UI's own "Save view" writes it.
    """
    import json

    keys = [f"metrics.`{c}`" for c in columns]
    # columnOrder: the columns in the order given (the UI sorts them by name otherwise), after the
    # run's name and date; the UI applies columnWidths only to the columns it orders.
    state: dict[str, Any] = {"selectedColumns": keys, "columnOrder": keys, "searchFilter": search}
    if group_by_tag is not None:
        state["groupBy"] = {
            "aggregateFunction": "min",
            "groupByKeys": [{"mode": "tag", "groupByData": group_by_tag}],
        }
    if column_width is not None:
        state["columnWidths"] = {k: column_width for k in keys}
    now = int(time.time() * 1000)
    tag = VIEW_TAG_PREFIX + key
    created = now
    with contextlib.suppress(Exception):  # keep the date a replaced view was first made
        created = int(json.loads(client.get_experiment(experiment_id).tags[tag])["createdAt"])
    value = {"name": name, "createdAt": created, "updatedAt": now, "state": json.dumps(state)}
    client.set_experiment_tag(experiment_id, tag, json.dumps(value))


# -- datasets -------------------------------------------------------------------------------------


def _files(path: Path) -> list[Path]:
    """The regular files of a data set at ``path`` (itself, or those under it), sorted."""
    if path.is_file():
        return [path]
    return sorted(p for p in path.rglob("*") if p.is_file())


def files_digest(paths: Sequence[str | Path], *, content: bool = True) -> str:
    """A 16-hex-digit fingerprint of the files of ``paths`` (files or folders, walked): SHA-256 of
    each file's name (relative to its folder) and bytes, in order; of names and sizes only when
    ``content`` is False or the files are over :data:`CONTENT_DIGEST_LIMIT` bytes in all."""
    import hashlib

    entries = []
    for root in map(Path, paths):
        for f in _files(root):
            name = f.name if f == root else f.relative_to(root).as_posix()
            entries.append((name, f, f.stat().st_size))
    content = content and sum(size for _, _, size in entries) <= CONTENT_DIGEST_LIMIT
    h = hashlib.sha256(b"content" if content else b"names-sizes")
    for name, f, size in entries:
        h.update(f"{name}\0{size}\0".encode())
        if content:
            with open(f, "rb") as stream:
                for block in iter(lambda: stream.read(1 << 20), b""):
                    h.update(block)
    return h.hexdigest()[:16]


def _definition_digest(definition: Mapping[str, Any]) -> str:
    """A 16-hex-digit fingerprint of what makes a generated data set."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(definition, sort_keys=True).encode()).hexdigest()[:16]


def _schema(resolution: int):
    """The samples' schema: a photo ``input`` (3 channels) and its ``maps`` (10 channels), float32,
    ``resolution`` pixels square."""
    import numpy as np
    from mlflow.types import Schema, TensorSpec

    r = int(resolution)
    return Schema([
        TensorSpec(np.dtype("float32"), (-1, 3, r, r), "input"),
        TensorSpec(np.dtype("float32"), (-1, 10, r, r), "maps"),
    ])  # fmt: skip


def _files_dataset(name: str, paths: Sequence[str | Path], resolution: int, *, content: bool):
    """A dataset of files: MLflow's local source (the first path), the digest of its files."""
    import json

    from mlflow.data.dataset_source_registry import get_dataset_source_from_json
    from mlflow.data.meta_dataset import MetaDataset

    paths = [Path(p).resolve() for p in paths]
    source = get_dataset_source_from_json(json.dumps({"uri": str(paths[0])}), source_type="local")
    digest = files_digest(paths, content=content)
    return MetaDataset(source, name=name, digest=digest, schema=_schema(resolution))


def _procedural_dataset(name: str, resolution: int, **definition: Any):
    """A generated dataset: MLflow's code source, tagged with what makes it; its digest covers that
    and the generator's version (there are no files to hash)."""
    from mlflow.data.code_dataset_source import CodeDatasetSource
    from mlflow.data.meta_dataset import MetaDataset

    tags = {
        "generator": "svbrdf_train.data.ProceduralMaterials",
        "svbrdf-train": importlib.metadata.version("svbrdf-train"),
        "resolution": int(resolution),
        **definition,
    }
    tags = {k: str(v) for k, v in tags.items()}
    digest = _definition_digest(tags)
    return MetaDataset(CodeDatasetSource(tags), name=name, digest=digest, schema=_schema(resolution))


def test_dataset(path: str | Path | None, resolution: int, *, count: int, seed: int, name: str | None = None):
    """The dataset a benchmark tests on, as MLflow records it (a meta dataset: no pixels).

    ``path`` (a Des18 folder or shards): named after it, MLflow's local source, the digest of its
    files' bytes (:func:`files_digest`). None: the procedural test set of ``count`` materials from
    ``seed`` at ``resolution``, a code source tagged with those, its digest theirs and the
    generator's version. The schema gives the tensors the models see: ``input`` and ``maps``.
    """
    if path is not None:
        return _files_dataset(name or Path(path).resolve().name, [path], resolution, content=True)
    return _procedural_dataset(
        name or f"procedural-test-seed{seed}", resolution, count=count, seed=seed, photos="des18"
    )


def fit_datasets(recipe) -> list[tuple[Any, str]]:
    """The data a fit of ``recipe`` trains and validates on, as ``(dataset, context)`` pairs
    (contexts ``training`` and ``validation``): procedural data by what makes it (seed, samples,
    capture); files by the names and sizes of their files (reading gigabytes of shards for a
    fingerprint is not cheap); each entry of a mix; the real validation set (``data.real_validation``)
    by its files' bytes."""
    d, r = recipe.data, recipe.train.resolution
    entries = list(d.mix) if d.source == "mix" and d.mix else [{"source": d.source, "path": d.path}]
    out: list[tuple[Any, str]] = []
    for i, entry in enumerate(entries):
        source = entry.get("source", "procedural")
        suffix = f"-{i}" if len(entries) > 1 else ""
        if source == "procedural":
            count = entry.get("count", d.count)
            validation = entry.get("validation", d.validation)
            for seed, n, context in ((d.seed, count, "training"), (d.seed + 1, validation, "validation")):
                if n:  # validation uses the next seed (DataSection.seed)
                    dataset = _procedural_dataset(f"procedural-seed{seed}{suffix}", r, count=n, seed=seed,
                                                  photos=d.capture)  # fmt: skip
                    out.append((dataset, context))
            continue
        path = entry.get("path") or d.path
        paths = [path] if isinstance(path, str) else list(path or ())
        if not paths or not all(Path(p).exists() for p in paths):
            continue  # the fit itself says what is missing
        name = Path(paths[0]).resolve().name + suffix
        out.append((_files_dataset(name, paths, r, content=False), "training"))
    if d.real_validation and Path(d.real_validation).exists():
        real = Path(d.real_validation)
        out.append((_files_dataset(real.resolve().name, [real], r, content=True), "validation"))
    return out


def log_datasets(client, run_id: str, datasets: Sequence[tuple[Any, str]]) -> None:
    """``(dataset, context)`` pairs as dataset inputs of run ``run_id`` (the UI's "Datasets")."""
    from mlflow.entities import DatasetInput, InputTag
    from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

    inputs = [
        DatasetInput(dataset._to_mlflow_entity(), [InputTag(MLFLOW_DATASET_CONTEXT, context)])
        for dataset, context in datasets
    ]
    if inputs:
        client.log_inputs(run_id, datasets=inputs)


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


# -- system metrics -------------------------------------------------------------------------------


def enable_system_metrics() -> None:
    """Turn MLflow's system metrics on for the runs this process and its children start (what
    ``--system-metrics`` does): CPU, memory, disk, network (and GPU with ``nvidia-ml-py``), sampled
    every 10 s as ``system/...`` metrics, shown on a run's "System metrics" tab."""
    _require_psutil()
    os.environ[SYSTEM_METRICS_ENV] = "true"


def _require_psutil() -> None:
    try:
        import psutil  # noqa: F401  (MLflow's system metrics read the machine through it)
    except ImportError:
        raise TrackingError(
            f"system metrics (--system-metrics, or {SYSTEM_METRICS_ENV}=true) need psutil: pip install psutil"
        ) from None


def _system_metrics_monitor(run_id: str, uri: str, *, resume: bool):
    """MLflow's system-metrics thread on run ``run_id``, started, when :data:`SYSTEM_METRICS_ENV`
    is on (MLflow starts it only for runs of its fluent API; these runs are the client's); else None."""
    if os.environ.get(SYSTEM_METRICS_ENV, "").strip().lower() not in ("true", "1"):
        return None
    _require_psutil()
    import logging

    from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

    logging.getLogger("mlflow.system_metrics").setLevel(logging.WARNING)  # no start/stop chatter
    monitor = SystemMetricsMonitor(run_id, resume_logging=resume, tracking_uri=uri)
    monitor.start()
    return monitor
