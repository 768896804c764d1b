"""The MLflow store a fit's runs go to: which one, checked before use, opened, its experiments.

Where runs go is MLflow's choice: ``MLFLOW_TRACKING_URI`` when set (a folder, a sqlite file or
an ``http://`` server), else MLflow's default (``sqlite:///mlflow.db`` in the working folder).
For a local store the experiment's artifact folder is set explicitly, beside the store
(``mlartifacts/`` next to ``mlflow.db``), so artifacts never land somewhere that depends on the
folder a later command runs in. A server keeps its own artifact root.

A store that cannot work is one :class:`TrackingError` line naming it and what to do: a file
that is not an MLflow store, a server that does not answer (:func:`check_store`), a store that
refuses a write (:func:`store_error`, exit status 3 like any failed write).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from urllib.parse import unquote, urlparse

from svbrdf_render.errors import OutputError

from ..errors import TrackingError

__all__ = [
    "EXPERIMENT_KIND_TAG", "EXPERIMENT_KIND", "OPEN_TIMEOUT_S", "MLFLOW_TABLES",
    "tracking_uri", "local_store_folder", "store_error", "quiet_store_logs", "check_store",
    "open_client", "experiment_id",
]  # fmt: skip

#: MLflow 3 keeps an experiment's kind in this tag, set on every experiment this project creates or
#: logs to; MLflow 3 UIs before workflow-based navigation chose an experiment's pages by it. MLflow
#: 3.17's UI does not read it: see :data:`.ui.WORKFLOW_QUERY`.
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"
#: How long the first request to a tracking server may take before the command gives up (and the
#: connection probe before it), unless ``MLFLOW_HTTP_REQUEST_TIMEOUT`` says otherwise; MLflow's own
#: default (120 s, retried 7 times with back-off: over 4 minutes) leaves a user staring at nothing.
OPEN_TIMEOUT_S = 10
#: Tables every MLflow SQL store has: an existing SQLite file without them is not an MLflow store.
MLFLOW_TABLES = frozenset({"experiments", "runs", "alembic_version"})


def tracking_uri() -> str:
    """The store runs go to: ``MLFLOW_TRACKING_URI``, else MLflow's default."""
    import mlflow

    return mlflow.get_tracking_uri()


def local_store_folder(uri: str) -> Path | None:
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
    The lock is :func:`svbrdf_render.plumbing.locked`, waiting: ``flock`` on POSIX (the
    lock file stays, so every process locks the same file, and a process of an earlier version,
    which took the same ``flock`` by hand or through ``filelock``, is still excluded), the
    system's own file lock through ``filelock`` on Windows.
    """
    parsed = urlparse(uri)
    if parsed.scheme != "sqlite":
        yield
        return
    from svbrdf_render.plumbing import locked

    db = Path(unquote(parsed.path)[1:]).resolve()
    with locked(db.with_name(db.name + ".lock")):
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


def store_error(what: str, uri: str, error: Exception) -> TrackingError:
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
    folder = local_store_folder(uri)
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
