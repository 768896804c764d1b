"""What MLflow's UI opens on: the addresses of its pages, and saved views of an experiment's runs.

Every address given here opens MLflow 3's model-training pages (:data:`WORKFLOW_QUERY`,
:func:`ui_page`); a saved view of an experiment's runs page picks its columns
(:func:`save_runs_view`).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from typing import Any
from urllib.parse import urlparse

from .store import local_store_folder

__all__ = ["WORKFLOW_QUERY", "LOCAL_UI", "VIEW_TAG_PREFIX", "ui_page", "ui_url", "ui_hint", "save_runs_view"]

#: The query parameter of a UI address that makes MLflow 3.17's UI open an experiment on its runs.
#: That UI (its bundle, ``mlflow/server/js/build/static/js/main.*.js``) takes an experiment's kind
#: from the *workflow type* whenever workflow-based navigation is on, which 3.17 hard-codes, and
#: never reads the kind tag (:data:`.store.EXPERIMENT_KIND_TAG`); the workflow type is the
#: address's ``workflowType`` parameter, else the browser's remembered choice (local storage
#: ``mlflow.workflowType_v1``, set by the "GenAI / Model training" switch at the top of the side
#: bar), else ``genai``. So a fresh browser opens every experiment on its GenAI overview
#: ("Traces 0") unless the address says otherwise: every address this module gives carries this
#: parameter.
WORKFLOW_QUERY = "workflowType=machine_learning"
#: Where ``mlflow ui`` serves by default: the addresses given for a local store start here.
LOCAL_UI = "http://127.0.0.1:5000"
#: An experiment tag ``<prefix><key>`` holds a saved view of its runs page (columns, filter,
#: grouping): the UI lists it under "Views" and opens it for ``?viewStateShareKey=<key>``.
VIEW_TAG_PREFIX = "mlflow.sharedViewState."


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
    elif local_store_folder(uri) is not None:
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
