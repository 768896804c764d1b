"""``svbrdf-bench run`` and ``report`` end to end on a tiny benchmark, and their refusals.

One benchmark (two recipes at the smoke size, a few steps, 6 test images) is run once per module
and checked from every side: the terminal table, the report folder, MLflow's parent/child runs,
and the report rebuilt from MLflow alone.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_bench.cli import cli
from svbrdf_render import read_image

TINY = ("--size", "smoke", "--set", "train.max_steps=6", "--set", "train.epochs=3", "--test-count", "6",
        "--experiment", "tests-bench")  # fmt: skip


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "report"
    real = tmp_path_factory.mktemp("real")
    from svbrdf_render import linear_to_srgb, write_image
    from svbrdf_train.data import ProceduralMaterials

    photos = ProceduralMaterials(3, 40, seed=11)  # sRGB-encoded as a phone saves them
    for i in range(3):
        write_image(real / f"photo{i}.png", linear_to_srgb(photos[i]["input"]))
    result = _invoke("run", "--models", "ours,radn", *TINY, "--real-data", real, "-o", out)
    assert result.exit_code == 0, result.output
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    return out, result, parent


def _section(text: str, title: str) -> list[str]:
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    end = next((i for i in range(start + 1, len(lines)) if not lines[i].strip()), len(lines))
    return lines[start:end]


def test_terminal_tables_in_the_paper_layout_with_time_columns(bench):
    _, result, _ = bench
    rmse = _section(result.stdout, "RMSE")
    assert rmse[1].split() == ["model", "normal", "diffuse", "roughness", "specular", "render"]
    assert [line.split()[0] for line in rmse[3:]] == ["ours", "radn"]
    time_table = _section(result.stdout, "Time and memory")
    for column in ("train samples/s", "latency 256px (ms)", "params (M)", "peak RSS (MB)"):
        assert column in time_table[1]
    assert "What accuracy costs" in result.stdout
    assert "ours vs radn" in result.stdout or "radn vs ours" in result.stdout
    assert "LPIPS skipped" in result.stdout  # stated, never downloaded


def test_report_folder_holds_markdown_tables_and_plots(bench):
    out, _, _ = bench
    for name in ("report.md", "results.csv", "results.json", "costs.csv"):
        assert (out / name).is_file(), name
    for name in ("learning_curves.png", "pareto.png", "comparison.png"):
        image = read_image(out / name)
        assert image.shape[0] == 3 and min(image.shape[1:]) > 100, name
    md = (out / "report.md").read_text()
    assert "![Validation render RMSE against training time](learning_curves.png)" in md
    rows = list(csv.DictReader(open(out / "results.csv")))
    assert [r["model"] for r in rows] == ["ours", "radn"]
    for r in rows:
        low, mean, high = (float(r[k]) for k in ("rmse_render_low", "rmse_render", "rmse_render_high"))
        assert low <= mean <= high


def test_mlflow_parent_and_one_child_per_model(bench):
    out, _, parent_id = bench
    client = _client()
    parent = client.get_run(parent_id)
    assert parent.info.status == "FINISHED" and parent.data.tags["svbrdf.kind"] == "bench"
    assert parent.data.params["preset"] == "quick" and parent.data.params["test_count"] == "6"
    logged = {a.path for a in client.list_artifacts(parent_id, "report")}
    assert {"report/report.md", "report/pareto.png", "report/learning_curves.png"} <= logged
    children = client.search_runs(
        [parent.info.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'"
    )
    assert sorted(c.data.tags["svbrdf.model"] for c in children) == ["ours", "radn"]
    results = {m["model"]: m for m in json.loads((out / "results.json").read_text())["models"]}
    for child in children:
        m = child.data.metrics
        assert child.data.tags["recipe"] == child.data.tags["svbrdf.model"]  # the fit itself is the child
        assert m["time/latency_ms"] > 0 and m["model/params"] > 0
        local = client.download_artifacts(child.info.run_id, "eval/per_sample.json", str(out.parent))
        per_sample = json.loads(open(local).read())
        assert len(per_sample["rmse/render"]) == 6
        # the logged mean is the mean of the per-sample values the report bootstraps
        assert m["test/rmse/render"] == pytest.approx(np.mean(per_sample["rmse/render"]))
        assert results[child.data.tags["svbrdf.model"]]["rmse_render"] == pytest.approx(m["test/rmse/render"])
        assert math.isfinite(m["test/ssim/normal"])


def test_report_rebuilds_the_same_tables_from_mlflow(bench, tmp_path):
    _, result, parent_id = bench
    again = _invoke("report", parent_id, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    for title in ("RMSE", "SSIM", "Time and memory", "What accuracy costs"):
        assert _section(again.stdout, title) == _section(result.stdout, title), title
    assert (tmp_path / "again" / "pareto.png").is_file()


def test_from_runs_reuses_a_finished_fit_as_a_child(bench, tmp_path):
    """``--from-runs radn`` takes the latest finished radn fit; only ours is trained again."""
    result = _invoke(
        "run",
        "--models",
        "ours",
        "--from-runs",
        "radn",
        *TINY,
        "--set",
        "train.max_steps=4",
        "-o",
        tmp_path / "r",
    )
    assert result.exit_code == 0, result.output
    assert "training radn" not in result.stderr and "training ours" in result.stderr
    parent = json.loads((tmp_path / "r" / "results.json").read_text())["parent_run"]
    client = _client()
    children = client.search_runs(
        [client.get_run(parent).info.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent}'"
    )
    reused = [c for c in children if c.data.tags["svbrdf.model"] == "radn"]
    assert len(reused) == 1 and "svbrdf.train_run" in reused[0].data.tags
    assert client.get_run(reused[0].data.tags["svbrdf.train_run"]).data.tags["recipe"] == "radn"


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["run", "--models", "ourz"], ["unknown model 'ourz'", "'ours'"]),
        (["run"], ["nothing to compare"]),
        (["run", "--models", "ours", "--test-data", "/no/such/folder"], ["/no/such/folder"]),
        (["run", "--models", "ours", "--preset", "huge"], ["huge"]),
        (["run", "--from-runs", "no-such-recipe-or-run"], ["no-such-recipe-or-run"]),
        (["report", "0123456789abcdef0123456789abcdef"], ["0123456789abcdef0123456789abcdef"]),
    ],
)
def test_bad_arguments_are_one_line_errors(args, needles):
    result = _invoke(*args)
    assert result.exit_code == 2, result.output
    # MLflow logs its own INFO lines when a store is first created; the error itself is one line
    err = "\n".join(line for line in result.stderr.splitlines() if " INFO mlflow." not in line)
    if not err.startswith("Usage:"):  # click's own usage errors show the usage line too
        assert err.startswith("svbrdf-bench: error: ") and err.strip().count("\n") == 0, err
    for needle in needles:
        assert needle in err


def test_an_empty_test_folder_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    result = _invoke("run", "--models", "ours", *TINY, "--test-data", tmp_path / "empty")
    assert result.exit_code == 2
    assert str(tmp_path / "empty") in result.stderr


def test_report_refuses_a_run_that_is_not_a_benchmark(bench):
    _, _, parent_id = bench
    client = _client()
    children = client.search_runs(
        [client.get_run(parent_id).info.experiment_id],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'",
    )
    result = _invoke("report", children[0].info.run_id)
    assert result.exit_code == 2 and "not the parent run" in result.stderr


def test_real_photos_add_the_self_consistency_figure(bench):
    """--real-data: each model's maps re-rendered under the flash fitted to each photo."""
    out, result, parent_id = bench
    table = _section(result.stdout, "Real photos")
    assert table[1].split()[:2] == ["model", "photos"]
    assert [line.split()[0] for line in table[3:]] == ["ours", "radn"]
    assert all(line.split()[1] == "3" for line in table[3:])
    rows = list(csv.DictReader(open(out / "results.csv")))
    for r in rows:
        assert 0 < float(r["real_rerender_rmse_median"]) < 1
    client = _client()
    children = client.search_runs(
        [client.get_run(parent_id).info.experiment_id],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'",
    )
    medians = {c.data.tags["svbrdf.model"]: c.data.metrics["real/rerender_rmse_median"] for c in children}
    assert {r["model"]: float(r["real_rerender_rmse_median"]) for r in rows} == pytest.approx(medians)
