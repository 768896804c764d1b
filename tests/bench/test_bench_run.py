"""``svbrdf-bench run`` and ``report`` end to end on a tiny benchmark, and their refusals.

One benchmark (two recipes at the smoke size, a few steps, 6 test images, plus the untrained
baselines ``mean`` and ``photo``) is run once per module and checked from every side: the terminal
table, the report folder, MLflow's parent/child runs, and the report rebuilt from MLflow alone.
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
    # A folder of two Des18 strips: the fits validate on it as well (val_real/ learning curves).
    from svbrdf_render import SVBRDF, write_des18

    strips = tmp_path_factory.mktemp("des18")
    materials = ProceduralMaterials(2, 64, seed=12)
    for i in range(2):
        s = materials[i]
        write_des18(strips / f"{i:07d};a;b.png", s["input"][None], SVBRDF.unpack(s["maps"][None]))
    result = _invoke("run", "--models", "ours,radn", *TINY, "--real-data", real, "--set",
                     f"data.real_validation={strips}", "-o", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    return out, result, parent


def _children(parent_id: str) -> list:
    client = _client()
    return client.search_runs(
        [client.get_run(parent_id).info.experiment_id],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'",
        order_by=["attributes.start_time ASC"],
    )


def _section(text: str, title: str) -> list[str]:
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    end = next((i for i in range(start + 1, len(lines)) if not lines[i].strip()), len(lines))
    return lines[start:end]


ROWS = ["ours", "radn", "mean", "photo"]  # the trained models, then the baselines


def test_terminal_tables_in_the_paper_layout_with_time_columns(bench):
    _, result, _ = bench
    rmse = _section(result.stdout, "RMSE")
    assert rmse[1].split() == ["model", "normal", "diffuse", "roughness", "specular", "render"]
    assert [line.split()[0] for line in rmse[3:]] == ROWS
    assert [line.split()[1] for line in rmse[5:]] == ["(baseline)", "(baseline)"]
    ssim = _section(result.stdout, "SSIM")
    assert "Wang et al. 2004" in ssim[0] and "sigma 1.5" in ssim[0]  # the variant is named
    assert [line.split()[0] for line in ssim[3:]] == ROWS
    time_table = _section(result.stdout, "Time and memory")
    for column in ("train time, budget clock (s)", "train wall (s)", "train samples/s", "latency 256px (ms)",
                   "params (M)", "peak RSS (MB)"):  # fmt: skip
        assert column in time_table[1]
    assert [line.split()[0] for line in time_table[3:]] == ROWS
    for line in time_table[5:]:  # baselines: no training, no parameters
        cells = line.split()
        assert cells[2:6] == ["-", "-", "-", "-"] and "0.00" in cells
    for line in time_table[3:5]:
        train, wall = (float(x) for x in line.split()[1:3])
        assert 0 < train and 0 < wall
    costs = _section(result.stdout, "What accuracy costs")
    assert costs[0] == "What accuracy costs (trained models)"
    assert [line.split()[:3] for line in costs[3:4]] in ([["ours", "vs", "radn"]], [["radn", "vs", "ours"]])
    assert not any("mean" in line or "photo" in line for line in costs[3:4])  # baselines have no cost
    assert "LPIPS skipped" in result.stdout  # stated, never downloaded


def test_the_report_says_which_clock_budgeted_the_training(bench):
    from svbrdf_train.training.clock import CLOCK_TAG

    out, result, parent_id = bench
    children = _children(parent_id)
    clocks = {c.data.tags.get(CLOCK_TAG) for c in children if "svbrdf.baseline" not in c.data.tags}
    assert clocks == {"cpu"}  # the trainer's default on a CPU
    line = "training time budgeted and reported on the CPU clock (process CPU time divided by torch threads)"
    assert line in result.stdout.splitlines()[:6]
    assert f"- {line}" in (out / "report.md").read_text()
    assert all(r["clock"] == "cpu" for r in json.loads((out / "results.json").read_text())["models"]
               if not r["baseline"])  # fmt: skip


def test_against_mean_table_and_headline(bench):
    """Every trained model is held against `mean`, map by map, and the headline says it in words."""
    out, result, _ = bench
    table = _section(result.stdout, "Against the mean baseline")
    assert table[1].split() == ["model", "normal", "diffuse", "roughness", "specular", "render"]
    assert [line.split()[0] for line in table[3:]] == ["ours", "radn"]
    rows = list(csv.DictReader(open(out / "against_mean.csv")))
    assert {(r["model"], r["column"]) for r in rows} == {(m, c) for m in ("ours", "radn") for c in
                                                        ("normal", "diffuse", "roughness", "specular", "render")}  # fmt: skip
    for r in rows:
        low, d, high = float(r["low"]), float(r["rmse_difference"]), float(r["high"])
        assert r["versus"] == "mean" and low <= d <= high
        expected = "within noise" if low <= 0 <= high else "beats" if high < 0 else "worse"
        assert r["verdict"] == expected
        rel = float(r["relative"])
        assert f"{d:+.4f} ({100 * rel:+.0f}%) [{low:+.4f}, {high:+.4f}] {expected}" in result.stdout
    # The headline: right under the first line, one sentence per trained model.
    lines = result.stdout.splitlines()
    headline = lines[1:3]
    md = (out / "report.md").read_text()
    for model, sentence in zip(["ours", "radn"], headline, strict=True):
        failing = [r["column"] for r in rows if r["model"] == model and r["verdict"] != "beats"]
        if failing:
            assert sentence.startswith(f"{model} does NOT beat the constant-map baseline `mean` on "
                                       f"{', '.join(failing)}: it has learned nothing")  # fmt: skip
        else:
            assert sentence.startswith(f"{model} beats the constant-map baseline `mean`")
        assert f"**{sentence}**" in md.split("## ")[0]  # at the top of report.md too
    # Six training steps learn nothing: at least the renderings are not better than constant maps.
    assert all("does NOT beat" in h and "render" in h for h in headline)
    assert "do not beat the constant-map baseline `mean` on renderings" in result.stdout
    assert json.loads((out / "results.json").read_text())["headline"] == headline


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
    assert [r["model"] for r in rows] == ROWS
    assert [r["baseline"] for r in rows] == ["False", "False", "True", "True"]
    assert (out / "against_mean.csv").is_file()
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
    children = _children(parent_id)
    assert sorted(c.data.tags["svbrdf.model"] for c in children) == sorted(ROWS)
    assert parent.data.params["baselines"] == "mean,photo"
    results = {m["model"]: m for m in json.loads((out / "results.json").read_text())["models"]}
    for child in children:
        m = child.data.metrics
        if child.data.tags["svbrdf.model"] in ("mean", "photo"):  # untrained, built from the registry
            assert child.data.tags["svbrdf.baseline"] == "true" and "recipe" not in child.data.tags
            assert child.info.status == "FINISHED" and child.data.params["model.name"] in ("mean", "photo")
            assert m["model/params"] == 0 and m["time/latency_ms"] > 0
            assert not any(k.startswith(("train/", "time/train")) for k in m)
        else:
            assert child.data.tags["recipe"] == child.data.tags["svbrdf.model"]  # the fit itself is the child
            assert m["time/latency_ms"] > 0 and m["model/params"] > 0
            assert m["time/train_steps_wall_s"] == m["train/total_wall_seconds"] > 0
        local = client.download_artifacts(child.info.run_id, "eval/per_sample.json", str(out.parent))
        per_sample = json.loads(open(local).read())
        assert len(per_sample["rmse/render"]) == 6
        # the logged mean is the mean of the per-sample values the report bootstraps
        assert m["test/rmse/render"] == pytest.approx(np.mean(per_sample["rmse/render"]))
        assert results[child.data.tags["svbrdf.model"]]["rmse_render"] == pytest.approx(m["test/rmse/render"])
        assert math.isfinite(m["test/ssim/normal"])


def test_report_rebuilds_the_same_tables_from_mlflow(bench, tmp_path):
    out, result, parent_id = bench
    again = _invoke("report", parent_id, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    for title in ("RMSE", "SSIM", "Against the mean baseline", "Real photos", "Time and memory",
                  "What accuracy costs", "Where the time went"):  # fmt: skip
        assert _section(again.stdout, title) == _section(result.stdout, title), title
    assert again.stdout.splitlines()[:5] == result.stdout.splitlines()[:5]  # the headline too
    assert (tmp_path / "again" / "pareto.png").is_file()
    assert (tmp_path / "again" / "against_mean.csv").read_text() == (out / "against_mean.csv").read_text()


def test_the_report_says_how_long_each_phase_took(bench):
    out, result, parent_id = bench
    table = _section(result.stdout, "Where the time went")
    phases = [line.split("  ")[0] for line in table[3:]]
    assert phases == ["checks and test set", "MLflow store", "training ours", "training radn", "scoring ours",
                      "scoring radn", "scoring the baseline mean", "scoring the baseline photo",
                      "total (before the report)"]  # fmt: skip
    seconds = [float(line.split()[-2]) for line in table[3:]]
    assert all(s >= 0 for s in seconds) and seconds[2] > 0 and seconds[3] > 0  # the fits take time
    assert seconds[-1] == pytest.approx(sum(seconds[:-1]), abs=0.1 * len(seconds))
    metrics = _client().get_run(parent_id).data.metrics
    assert sorted(k for k in metrics if k.startswith("phase/"))[2] == "phase/03 training ours"
    assert "## Where the time went" in (out / "report.md").read_text()


def test_learning_curves_read_both_validation_sets(bench):
    """The fits validated on the real-material folder too: the report reads both curves."""
    from svbrdf_bench.report import build_report

    _, _, parent_id = bench
    report = build_report(parent_id)
    for e in report.trained:
        assert e.curve[0] and e.curve_real[0], e.label
        assert e.curve[0] == e.curve_real[0]  # logged at the same steps
        assert all(0 < v < 1 for v in e.curve_real[1])
    assert all(not e.curve[0] and not e.curve_real[0] for e in report.models if e.baseline)


def test_no_baselines_drops_them(bench, tmp_path):
    """--no-baselines: only the models, no comparison with `mean`, and the headline says so."""
    result = _invoke("run", "--from-runs", "ours", *TINY, "--no-baselines", "-o", tmp_path / "r")
    assert result.exit_code == 0, result.output
    assert "training ours" not in result.stderr  # reused, not trained
    assert [line.split()[0] for line in _section(result.stdout, "RMSE")[3:]] == ["ours"]
    assert "Against the mean baseline" not in result.stdout and "(baseline)" not in result.stdout
    assert result.stdout.splitlines()[1].startswith("No baseline was evaluated (--no-baselines)")
    parent = json.loads((tmp_path / "r" / "results.json").read_text())["parent_run"]
    assert [c.data.tags["svbrdf.model"] for c in _children(parent)] == ["ours"]
    assert not (tmp_path / "r" / "against_mean.csv").exists()
    again = _invoke("report", parent)
    assert again.stdout == result.stdout


def test_a_model_named_like_a_baseline_is_refused(tmp_path):
    from svbrdf_train.recipe import recipe_path

    (tmp_path / "mean.yaml").write_text(recipe_path("radn").read_text())
    result = _invoke("run", "--models", tmp_path / "mean.yaml", *TINY, "-o", tmp_path / "r")
    assert result.exit_code == 2
    err = [line for line in result.stderr.splitlines() if " INFO mlflow." not in line]
    assert len(err) == 1 and "name of a baseline" in err[0] and "--no-baselines" in err[0]


def test_from_runs_reuses_a_finished_fit_as_a_child(bench, tmp_path):
    """``--from-runs radn`` takes the latest finished radn fit; only ours is trained again."""
    result = _invoke(
        "run",
        "--models",
        "ours",
        "--from-runs",
        "radn",
        *(a.replace("train.max_steps=6", "train.max_steps=4") for a in TINY),  # a field once
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
    fitted = client.get_run(reused[0].data.tags["svbrdf.train_run"])
    assert fitted.data.tags["recipe"] == "radn"
    # The reused child carries the fit's params, as a child trained in the benchmark (the fit's own
    # run) does: the runs table compares them by recipe field.
    assert reused[0].data.params == fitted.data.params and reused[0].data.params["loss.adv"] == "0.0"


def test_the_benchmark_s_experiment_opens_in_the_model_training_view(bench):
    client = _client()
    experiment = client.get_experiment(client.get_run(bench[2]).info.experiment_id)
    assert experiment.name == "tests-bench"
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"


def test_a_reused_child_carries_every_param_of_its_fit():
    """More params than MLflow takes in one batch (100), all copied; the recipe tag is the fit's."""
    from mlflow.entities import Param

    from svbrdf_bench.children import reused_child
    from svbrdf_bench.layout import TRAIN_RUN_TAG

    client = _client()
    experiment = client.create_experiment("tests-reused-child")
    fitted = client.create_run(experiment, tags={"recipe": "ours"}).info.run_id
    params = {f"section.field_{i:03d}": str(i * 0.5) for i in range(150)}
    items = [Param(k, v) for k, v in params.items()]
    client.log_batch(fitted, params=items[:100])
    client.log_batch(fitted, params=items[100:])
    parent = client.create_run(experiment).info.run_id
    child = client.get_run(reused_child(client, experiment, parent, "ours-second", fitted))
    assert child.data.params == params
    assert child.data.tags[TRAIN_RUN_TAG] == fitted and child.data.tags["mlflow.parentRunId"] == parent
    assert child.data.tags["recipe"] == "ours" and child.info.run_name == "ours-second (reused)"


def test_the_preset_s_overrides_reach_every_fit(bench):
    """The quick preset gives the fits 10x the cpu size's samples, so that its time budget, not the
    end of the recipe's epochs, stops the faster models; the parent run records the overrides."""
    from svbrdf_bench.presets import PRESETS

    _, _, parent = bench
    assert PRESETS["quick"].overrides == ("data.count=20000",)
    fits = [c for c in _children(parent) if "svbrdf.baseline" not in c.data.tags]
    assert fits and all(c.data.params["data.count"] == "20000" for c in fits)
    assert "data.count=20000" in _client().get_run(parent).data.params["overrides"]


def test_two_reused_fits_of_one_recipe_get_a_row_each(bench, tmp_path):
    """Two fits of ``ours`` given by run id stay two rows (the second named after its run), and the
    header says the reused fits keep their own training budgets instead of quoting the preset's."""
    from svbrdf_train.cli import cli as train_cli

    client = _client()
    fit = CliRunner().invoke(
        train_cli,
        ["fit", "-q", "--recipe", "ours", "--size", "smoke", "--out", str(tmp_path / "fit"),
         "--experiment", "tests-bench", "--run-name", "ours-second"],
        catch_exceptions=False,
    )  # fmt: skip
    assert fit.exit_code == 0, fit.output
    second = json.loads((tmp_path / "fit" / "last.json").read_text())["run_id"]
    first = next(c for c in _children(bench[2]) if c.data.tags["svbrdf.model"] == "ours").info.run_id
    ids = [first, second]
    result = _invoke("run", "--from-runs", ",".join(ids), *TINY, "-o", tmp_path / "r")
    assert result.exit_code == 0, result.output
    rows = [line.split()[0] for line in _section(result.stdout, "RMSE")[3:]]
    assert rows[0] == "ours" and rows[1] not in ("ours", "mean", "photo") and rows[2:] == ["mean", "photo"]
    assert rows[1] == "ours-second"
    assert "reused fits, each with its own training budget" in result.stdout.splitlines()[0]
    assert "min of training per model" not in result.stdout.splitlines()[0]
    # The benchmark's children of reused fits carry the recipe tag too, and are finished: a recipe
    # name must still resolve to a fit with a checkpoint, never to such a child.
    from svbrdf_bench.children import resolve_reuse
    from svbrdf_bench.layout import TRAIN_RUN_TAG

    ((label, picked),) = resolve_reuse(["ours"])
    assert label == "ours" and TRAIN_RUN_TAG not in client.get_run(picked).data.tags


@pytest.mark.parametrize("command", ["run", "render"])
def test_the_experiment_is_the_flag_else_mlflow_experiment_name_else_svbrdf_bench(command, monkeypatch):
    def chosen(*args):
        return cli.commands[command].make_context(command, list(args)).params["experiment"]

    assert chosen() == "svbrdf-bench"
    monkeypatch.setenv("MLFLOW_EXPERIMENT_NAME", "from-the-environment")
    assert chosen() == "from-the-environment"
    assert chosen("--experiment", "from-the-flag") == "from-the-flag"
    assert "MLFLOW_EXPERIMENT_NAME" in _invoke(command, "--help").output


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
    assert [line.split()[0] for line in table[3:]] == ROWS  # the photo baseline beside the models
    assert all(line.split()[-5] == "3" for line in table[3:])
    after = result.stdout.split("\n".join(table))[1].splitlines()[2]
    assert after.startswith("Re-rendering RMSE measures consistency with the photo, not correctness")
    rows = list(csv.DictReader(open(out / "results.csv")))
    for r in rows:
        assert 0 <= float(r["real_rerender_rmse_median"]) < 1
    # Copying the photo into the diffuse map re-renders the photo almost exactly: consistency, not truth.
    photo_row = next(r for r in rows if r["model"] == "photo")
    assert float(photo_row["real_rerender_rmse_median"]) < min(
        float(r["real_rerender_rmse_median"]) for r in rows if r["model"] in ("ours", "radn")
    )
    client = _client()
    children = client.search_runs(
        [client.get_run(parent_id).info.experiment_id],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'",
    )
    medians = {c.data.tags["svbrdf.model"]: c.data.metrics["real/rerender_rmse_median"] for c in children}
    assert {r["model"]: float(r["real_rerender_rmse_median"]) for r in rows} == pytest.approx(medians)


def test_a_fine_tuned_fit_counts_the_time_behind_its_starting_weights(bench, tmp_path):
    """A fit started with ``--init`` is drawn from where its parent's training stopped, and the
    report says where its weights came from."""
    from svbrdf_bench.report import build_report
    from svbrdf_train.cli import cli as train_cli

    # the benchmark trained ours itself: its child run is the fit
    parent_fit = next(c for c in _children(bench[2]) if c.data.tags["svbrdf.model"] == "ours").info.run_id
    before = _client().get_run(parent_fit).data.metrics["train/total_seconds"]
    fit = CliRunner().invoke(
        train_cli,
        ["fit", "-q", "--recipe", "ours", "--size", "smoke", "--out", str(tmp_path / "fit"),
         "--experiment", "tests-bench", "--run-name", "ours-tuned", "--init", parent_fit],
        catch_exceptions=False,
    )  # fmt: skip
    assert fit.exit_code == 0, fit.output
    tuned = json.loads((tmp_path / "fit" / "last.json").read_text())["run_id"]
    result = _invoke("run", "--from-runs", tuned, *TINY, "--no-baselines", "-o", tmp_path / "r")
    assert result.exit_code == 0, result.output
    assert f"was fine-tuned from run {parent_fit} (fit --init)" in result.stdout
    (entry,) = build_report(json.loads((tmp_path / "r" / "results.json").read_text())["parent_run"]).trained
    own = _client().get_metric_history(tuned, "val/train_seconds")
    assert entry.curve[0] and min(entry.curve[0]) == pytest.approx(before + min(m.value for m in own), abs=0.2)


# -- svbrdf-bench export: the paper table, from the parent run alone ---------------------------------


def test_export_prints_the_paper_table_from_the_parent_run(bench, tmp_path):
    out, _, parent_id = bench
    md = _invoke("export", parent_id)
    assert md.exit_code == 0, md.output
    lines = md.stdout.splitlines()
    assert lines[0].startswith("**Table.** RMSE (lower is better) on ") and "6 test images" in lines[0]
    assert f"parent run {parent_id}" in lines[0] and "`mean`: constant maps" in lines[0]
    rows = [line.split(" | ")[0][2:] for line in lines[4:]]
    assert rows == ["ours", "radn", "mean (baseline)", "photo (baseline)"]
    records = {r["model"]: r for r in json.loads((out / "results.json").read_text())["models"]}
    for i, column in enumerate(("normal", "diffuse", "roughness", "specular", "render"), start=1):
        cells = {row: line.split(" | ")[i].strip(" |") for row, line in zip(rows, lines[4:], strict=True)}
        best = min(records, key=lambda m: records[m][f"rmse_{column}"])
        assert cells[best if best in cells else f"{best} (baseline)"].startswith("**"), column
        assert f"{records['ours'][f'rmse_{column}']:.3f} [" in cells["ours"]  # the report's own figures
    tex = tmp_path / "table.tex"
    latex = _invoke("export", parent_id, "--format", "latex", "-o", tex)
    assert latex.exit_code == 0 and latex.stdout == "" and f"export: {tex}" in latex.stderr
    text = tex.read_text()
    for needle in (r"\begin{table}", r"\begin{tabular}{lccccc}", r"\toprule", r"\bottomrule", r"\end{table}",
                   r"95\% percentile-bootstrap", r"\texttt{mean}", r"\textbf{"):  # fmt: skip
        assert needle in text, needle
    assert "photo (baseline) & " in text


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--format", "html"], "unknown export format 'html': choose one of latex, markdown"),
        (["--format", "latex"], "not the parent run of an svbrdf-bench run"),  # a child run's id
    ],
)
def test_export_errors_are_one_line_exit_2(bench, args, needle):
    child = _children(bench[2])[0].info.run_id
    result = _invoke("export", child, *args)
    assert result.exit_code == 2 and result.stdout == ""
    err = [line for line in result.stderr.splitlines() if " INFO mlflow." not in line]
    assert err == [f"svbrdf-bench: error: {err[0].split('error: ', 1)[1]}"] and needle in err[0]


def test_export_of_an_unknown_run_and_its_help():
    result = _invoke("export", "0123456789abcdef0123456789abcdef", "--format", "latex")
    assert result.exit_code == 2 and "no MLflow run 0123456789abcdef0123456789abcdef" in result.stderr
    helped = _invoke("export", "--help")
    assert helped.exit_code == 0
    assert "svbrdf-bench export 3f2a... --format latex -o table.tex" in helped.stdout
    assert "Examples:" in helped.stdout and "-f, --format latex|markdown" in helped.stdout
