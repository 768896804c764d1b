"""What a researcher sees of a benchmark in MLflow's UI, checked in the UI itself.

One tiny benchmark (one recipe at the smoke size, a few steps, 6 procedural test images, the
baselines ``mean`` and ``photo``) in an MLflow store of its own; then the store as MLflow shows it
(the parent run's description, metrics and report; the children's datasets and source; the
experiment's saved view), and the UI's own server (``mlflow server`` on loopback) opened in headless
Chromium with a fresh profile on the addresses the benchmark prints: the experiment opens on the
runs table with the models' test figures, not on MLflow 3's GenAI pages ("Traces 0"), and the parent
run's page shows the verdict and links the report.

The browser tests skip where Chromium is missing, and fail where CI is set (tests/conftest.py).
"""

from __future__ import annotations

import html
import json
import os
import re
import subprocess
import sys
import tempfile

import pytest
from click.testing import CliRunner

from conftest import CHROMIUM, free_port, require_chromium, serving
from svbrdf_bench.cli import cli

EXPERIMENT = "tests-bench-ui"
TINY = ("--size", "smoke", "--set", "train.max_steps=6", "--set", "train.epochs=3", "--test-count", "6",
        "--experiment", EXPERIMENT)  # fmt: skip
MAPS = ("normal", "diffuse", "roughness", "specular", "render")


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """The benchmark, run in a store of its own: ``(store uri, client, results.json, output)``."""
    from mlflow import MlflowClient

    folder = tmp_path_factory.mktemp("ui-store")
    uri = f"sqlite:///{folder}/mlflow.db"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MLFLOW_TRACKING_URI", uri)
        out = folder / "report"
        args = ["run", "--models", "ours", *TINY, "-o", str(out)]
        result = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    return uri, MlflowClient(uri), results, result.output


def _children(client, parent_id: str) -> list:
    experiment = client.get_run(parent_id).info.experiment_id
    return client.search_runs([experiment], filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'")


def _inputs(run) -> list[tuple[str, object]]:
    """``(context, dataset)`` of each dataset input of ``run``."""
    inputs = run.inputs.dataset_inputs
    return [({t.key: t.value for t in d.tags}["mlflow.data.context"], d.dataset) for d in inputs]


# -- the store, as the UI reads it --------------------------------------------------------------


def test_the_parent_run_describes_the_verdict_and_links_the_report(bench):
    from svbrdf_train.tracking import ui_page

    _, client, results, _ = bench
    parent = client.get_run(results["parent_run"])
    note = parent.data.tags["mlflow.note.content"]
    assert results["headline"] and all(f"**{h}**" in note for h in results["headline"])
    report = ui_page(parent.info.experiment_id, parent.info.run_id, artifact="report/report.md")
    assert f"]({report})" in note  # a markdown link to the report, an artifact of the run
    assert "report/report.md" in {a.path for a in client.list_artifacts(parent.info.run_id, "report")}
    for rec in results["models"]:  # the table: each row's render RMSE and its interval
        r = f"{rec['rmse_render']:.4f} [{rec['rmse_render_low']:.4f}, {rec['rmse_render_high']:.4f}]"
        assert re.search(rf"^\| {re.escape(rec['model'])} \| {re.escape(r)} \|", note, re.M), rec["model"]


def test_the_parent_run_holds_the_comparison_as_metrics_with_interval_bounds(bench):
    _, client, results, _ = bench
    metrics = client.get_run(results["parent_run"]).data.metrics
    assert [r["model"] for r in results["models"]] == ["ours", "mean", "photo"]
    for rec in results["models"]:
        for c in MAPS:
            value, low, high = (metrics[f"{rec['model']}/rmse_{c}{s}"] for s in ("", "_lower", "_upper"))
            assert value == pytest.approx(rec[f"rmse_{c}"], rel=1e-12)
            assert (low, high) == pytest.approx((rec[f"rmse_{c}_low"], rec[f"rmse_{c}_high"]), rel=1e-12)
            assert low <= value <= high
            assert metrics[f"{rec['model']}/ssim_{c}"] == pytest.approx(rec[f"ssim_{c}"], rel=1e-12)
        assert metrics[f"{rec['model']}/time_latency_ms"] == pytest.approx(rec["time_latency_ms"], rel=1e-12)
    assert not any(k.endswith(("_low", "_high")) for k in metrics)  # renamed: they sort after the mean


def test_every_run_logs_the_test_set_and_where_it_comes_from(bench):
    """Children and parent carry the one test set (context ``test``, a procedural source: its seed
    and size; no pixels stored); the fit trained here its own data too and its own source
    (``svbrdf-train fit``), the baselines the benchmark's (``svbrdf-bench run``), both at this commit."""
    from svbrdf_bench.presets import TEST_SEED
    from svbrdf_train.tracking import git_revision

    _, client, results, _ = bench
    parent = client.get_run(results["parent_run"])
    children = _children(client, results["parent_run"])
    assert sorted(c.data.tags["svbrdf.model"] for c in children) == ["mean", "ours", "photo"]
    tested = []
    for run in [parent, *children]:
        (dataset,) = [d for context, d in _inputs(run) if context == "test"]
        tested.append((dataset.name, dataset.digest))
        source = json.loads(dataset.source)["tags"]
        assert (source["seed"], source["count"]) == (str(TEST_SEED), "6")
    assert len(set(tested)) == 1
    sha, _ = git_revision()
    for run in children:
        fit = run.data.tags["svbrdf.model"] == "ours"
        assert run.data.tags["mlflow.source.name"] == ("svbrdf-train fit" if fit else "svbrdf-bench run")
        assert run.data.tags["mlflow.source.git.commit"] == sha
        assert {c for c, _ in _inputs(run)} == ({"training", "validation", "test"} if fit else {"test"})
    assert parent.data.tags["mlflow.source.name"] == "svbrdf-bench run"


def test_the_experiment_is_tagged_and_holds_the_view_the_links_open(bench):
    from svbrdf_bench.mlflow_view import BENCH_COLUMNS, BENCH_VIEW, BENCHMARK_TAG
    from svbrdf_train.tracking import FIT_VIEW, VIEW_TAG_PREFIX, ui_url

    uri, client, results, output = bench
    experiment = client.get_experiment_by_name(EXPERIMENT)
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    assert VIEW_TAG_PREFIX + FIT_VIEW not in experiment.tags  # the fits of a benchmark are its children
    view = json.loads(experiment.tags[VIEW_TAG_PREFIX + BENCH_VIEW])
    state = json.loads(view["state"])
    assert state["selectedColumns"] == [f"metrics.`{c}`" for c in BENCH_COLUMNS]
    assert state["groupBy"]["groupByKeys"] == [{"mode": "tag", "groupByData": BENCHMARK_TAG}]
    matched = client.search_runs([experiment.experiment_id], filter_string=state["searchFilter"])
    children = _children(client, results["parent_run"])
    assert {r.info.run_id for r in matched} == {c.info.run_id for c in children}
    link = ui_url(uri, experiment.experiment_id, view=BENCH_VIEW)
    assert link in output and "workflowType=machine_learning" in link


# -- the UI itself --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ui(bench, tmp_path_factory):
    """MLflow's own UI server on the benchmark's store, on loopback: its base address."""
    require_chromium()
    uri = bench[0]
    base = f"http://127.0.0.1:{free_port()}"
    command = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri, "--host", "127.0.0.1",
               "--port", base.rsplit(":", 1)[1], "--workers", "1"]  # fmt: skip
    log = tmp_path_factory.mktemp("ui") / "server.log"
    with serving(command, f"{base}/health", log, env={**os.environ, "MLFLOW_TRACKING_URI": uri}, timeout=180):
        yield base


def _page(url: str) -> tuple[str, str]:
    """``(html, text)`` of ``url`` in headless Chromium with a fresh profile, after its scripts ran."""
    with tempfile.TemporaryDirectory(prefix="svbrdf-chromium-") as profile:
        r = subprocess.run(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={profile}", "--window-size=1600,900", "--virtual-time-budget=20000",
             "--dump-dom", url],
            capture_output=True, text=True, timeout=180,
        )  # fmt: skip
    assert r.returncode == 0 and r.stdout, f"chromium failed: {r.stderr[-1000:]}"
    body = re.sub(r"<script.*?</script>|<style.*?</style>", " ", r.stdout, flags=re.S)
    text = html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", body)))
    return r.stdout, text


def _printed_link(output: str, base: str) -> str:
    """The address the benchmark printed, on the test's server instead of ``mlflow ui``'s default."""
    from svbrdf_train.tracking import LOCAL_UI

    found = re.search(re.escape(LOCAL_UI) + r"/(#/experiments/\S+)", output)
    assert found, output[-2000:]
    return f"{base}/{found[1]}"


def test_the_printed_link_opens_the_runs_table_with_the_models_figures(bench, ui):
    _, client, results, output = bench
    _, text = _page(_printed_link(output, ui))
    assert "Traces 0" not in text and "Start tracing" not in text, text[:1500]
    assert "svbrdf: benchmarks (test figures)" in text  # the saved view is open
    for column in ("test/rmse/render", "test/rmse/normal"):  # the grid draws the columns in view only
        assert column in text, text[:1500]
    for child in _children(client, results["parent_run"]):
        assert child.info.run_name in text
        value = child.data.metrics["test/rmse/render"]
        assert repr(value) in text, (child.info.run_name, value)  # the figure itself, in full


def test_the_parent_run_page_shows_the_verdict_and_links_the_report(bench, ui):
    from svbrdf_train.tracking import ui_page

    _, client, results, _ = bench
    parent = client.get_run(results["parent_run"])
    page, text = _page(f"{ui}/{ui_page(parent.info.experiment_id, parent.info.run_id)}")
    verdict = results["headline"][0].replace("`", "")
    assert verdict in text, text[:3000]
    report = ui_page(parent.info.experiment_id, parent.info.run_id, artifact="report/report.md")
    assert f'href="{html.escape(report)}"' in page
    assert "ours/rmse_render_lower" in text  # the metrics table of the run
    assert "procedural-test-seed" in text  # its dataset
