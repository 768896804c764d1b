"""``svbrdf-bench run --refine 0,N``: refinement budgets as an axis of the benchmark.

One tiny benchmark (a reference model file of the smoke generator, 3 procedural test images at
32 px, the baselines, budgets 0 and 12 on the eager renderer; nothing is trained) is run once
per module and checked from every side: a row per budget with finite figures, the refined
re-rendering of each photo closer to it, the pure-optimisation baseline named and held against
the refined model, MLflow's children, the plot, and the report rebuilt from MLflow alone.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from test_bench_models import LABEL, _children, _errors, tiny_model
from test_bench_run import _invoke, _section

from svbrdf_bench.errors import BenchError
from svbrdf_bench.refinement import parse_budgets, parse_flash, refined_label
from svbrdf_render import read_image

STEPS = 12
REFINED = refined_label(LABEL, STEPS, "fold0")
#: Row labels (MLflow's svbrdf.model), in the report's order: each row, then its refined row.
LABELS = [LABEL, REFINED, "mean", f"mean +refine {STEPS}", "photo", f"photo +refine {STEPS}"]
FAST = ("--test-count", "3", "--refine-backend", "eager", "--experiment", "tests-bench-refine")


@pytest.fixture(scope="module")
def refined(tmp_path_factory):
    folder = tmp_path_factory.mktemp("refine")
    tiny_model(folder / "fold0.pt")
    out = folder / "report"
    result = _invoke("run", "--from-models", folder / "fold0.pt", *FAST, "--refine", f"0,{STEPS}", "-o", out)
    assert result.exit_code == 0, result.output
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    return out, result, parent


def _records(out) -> dict[str, dict]:
    return {r["model"]: r for r in json.loads((out / "results.json").read_text())["models"]}


def test_the_labels_put_the_budget_after_the_name():
    assert REFINED == "fold0 +refine 12 (reference: ours, 32 px, 8.3k steps, 1.1 h CPU; not equal-budget)"
    assert refined_label("ours", 200) == "ours +refine 200"


def test_one_row_per_budget_with_finite_figures(refined):
    out, result, _ = refined
    records = _records(out)
    assert list(records) == LABELS
    for label, r in records.items():
        assert r["refine_steps"] == (STEPS if "+refine" in label else 0)
        for key in ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_render",
                    "ssim_render", "photo_rerender_rmse", "time_seconds_per_image"):  # fmt: skip
            assert math.isfinite(r[key]), (label, key)
        assert r["rmse_render_low"] <= r["rmse_render"] <= r["rmse_render_high"]
        assert r["time_seconds_per_image"] > 0
    for label in LABELS[::2]:  # refining costs time: each refined row is slower than its row
        assert (
            records[refined_label(label, STEPS, "fold0")]["time_seconds_per_image"]
            > records[label]["time_seconds_per_image"]
        )
    # The terminal tables: each row followed by its refined row, the budget in the label.
    rmse = _section(result.stdout, "RMSE")
    names = [LABEL, REFINED, "mean (baseline)", f"mean +refine {STEPS} (pure-optimisation baseline)",
             "photo (baseline)", f"photo +refine {STEPS} (baseline)"]  # fmt: skip
    assert [next(n for n in names if line.startswith(n + "  ")) for line in rmse[3:]] == names
    table = _section(result.stdout, "Refinement: accuracy against capture time")
    assert [line.split("  ")[0] for line in table[3:]] == names
    assert [r["model"] for r in csv.DictReader(open(out / "results.csv"))] == LABELS


def test_refined_maps_re_render_the_photo_closer(refined):
    """What refinement optimises: the maps under the photo's flash against the photo itself.

    (The ``photo`` baseline is left out: its diffuse map is the photo, so it re-renders it almost
    exactly before any step, and the prior-weighted log loss need not lower a display RMSE there.)
    """
    out, _, _ = refined
    records = _records(out)
    for label in (LABEL, "mean"):
        before = records[label]["photo_rerender_rmse"]
        after = records[refined_label(label, STEPS, "fold0")]["photo_rerender_rmse"]
        assert after < before, (label, before, after)


def test_the_pure_optimisation_baseline_is_named_and_held_against(refined):
    out, result, _ = refined
    rows = list(csv.DictReader(open(out / "against_mean.csv")))
    versus = {r["model"]: r["versus"] for r in rows}
    assert versus == {LABEL: "mean", REFINED: f"mean +refine {STEPS}"}
    headline = result.stdout.splitlines()[1:3]
    assert headline[0].startswith(f"{LABEL} ") and "constant-map baseline `mean`" in headline[0]
    assert headline[1].startswith(f"{REFINED} ")
    assert f"the pure-optimisation baseline `mean +refine {STEPS}`" in headline[1]
    md = (out / "report.md").read_text()
    assert f"| mean +refine {STEPS} (pure-optimisation baseline) |" in md
    assert "refines constant maps: the pure-optimisation baseline" in md
    time_table = _section(result.stdout, "Time and memory")
    assert any(line.startswith(f"mean +refine {STEPS} (pure-optimisation baseline)") for line in time_table)
    assert any(line.startswith(f"fold0 +refine {STEPS} (reference)") for line in time_table)


def test_the_capture_time_plot_is_written(refined):
    out, _, _ = refined
    image = read_image(out / "accuracy_vs_capture_time.png")
    assert image.shape[0] == 3 and image.shape[2] > image.shape[1] > 100  # two panels side by side
    md = (out / "report.md").read_text()
    assert "(accuracy_vs_capture_time.png)" in md


def test_mlflow_children_per_budget(refined):
    _, _, parent = refined
    from mlflow import MlflowClient

    client = MlflowClient()
    assert client.get_run(parent).data.params["refine_budgets"] == f"0,{STEPS}"
    assert client.get_run(parent).data.params["refine_backend"] == "eager"
    children = _children(parent)
    assert sorted(children) == sorted(LABELS)
    for label in LABELS[::2]:
        base, child = children[label], children[refined_label(label, STEPS, "fold0")]
        tags, m = child.data.tags, child.data.metrics
        assert tags["svbrdf.refine_steps"] == str(STEPS) and tags["svbrdf.refined_from"] == base.info.run_id
        assert tags.get("svbrdf.baseline") == base.data.tags.get("svbrdf.baseline")
        assert tags.get("svbrdf.reference") == base.data.tags.get("svbrdf.reference")
        assert m["refine/steps"] == STEPS and m["refine/steps_taken"] == STEPS
        assert (
            child.data.params["refine.steps"] == str(STEPS) and child.data.params["refine.backend"] == "eager"
        )
        assert m["time/seconds_per_image"] == pytest.approx(
            m["time/network_seconds_per_image"] + m["time/refine_seconds_per_image"]
        )
        assert child.info.status == "FINISHED"
        # the unrefined row gets its photo re-rendering and seconds too, and keeps everything else
        assert (
            "test/photo/rerender_rmse" in base.data.metrics and "time/seconds_per_image" in base.data.metrics
        )
        assert "svbrdf.refine_steps" not in base.data.tags


def test_report_rebuild_keeps_the_refined_rows(refined, tmp_path):
    out, result, parent = refined
    again = _invoke("report", parent, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    for title in ("RMSE", "SSIM", "Against the mean baseline", "Refinement: accuracy against capture time",
                  "Time and memory"):  # fmt: skip
        assert _section(again.stdout, title) == _section(result.stdout, title), title
    assert again.stdout.splitlines()[:6] == result.stdout.splitlines()[:6]
    assert (tmp_path / "again" / "accuracy_vs_capture_time.png").is_file()
    assert (tmp_path / "again" / "results.csv").read_text() == (out / "results.csv").read_text()


def test_without_refine_nothing_changes(refined):
    """The default, --refine 0: no refined rows, no capture-time table, plot or figures."""
    from svbrdf_bench.report import build_report, terminal

    _, _, parent = refined
    report = build_report(parent)
    report.models = [e for e in report.models if not e.refine_steps]
    for e in report.models:  # as a run without --refine logs them
        e.per_sample.pop("photo/rerender_rmse")
        e.figures = {k: v for k, v in e.figures.items() if "seconds_per_image" not in k}
    text = terminal(report)
    assert "+refine" not in text and "Refinement" not in text and "pure-optimisation" not in text
    assert "s/image" not in text


@pytest.fixture(scope="module")
def refined_real(tmp_path_factory):
    """--refine with --real-data: two tiny real photos (no ground truth), the model file alone;
    the rows of the real-photo sheet recorded as the runner hands them to the plot."""
    from svbrdf_bench import plots
    from svbrdf_render import linear_to_srgb, write_image
    from svbrdf_train.data import ProceduralMaterials

    folder = tmp_path_factory.mktemp("refine-real")
    tiny_model(folder / "fold0.pt")
    real = folder / "photos"
    real.mkdir()
    photos = ProceduralMaterials(2, 40, seed=11)
    for i in range(2):
        write_image(real / f"photo{i}.png", linear_to_srgb(photos[i]["input"]))
    sheets = []
    draw = plots.comparison_grid

    def recording(rows, columns, path, **kw):
        sheets.append((str(path), [label for label, _ in rows], list(columns)))
        return draw(rows, columns, path, **kw)

    out = folder / "report"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "comparison_grid", recording)
        result = _invoke("run", "--from-models", folder / "fold0.pt", *FAST, "--no-baselines", "--refine",
                         f"0,{STEPS}", "--real-data", real, "-o", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    return out, result, sheets


def test_real_photos_get_the_refined_rows(refined_real):
    """Each refined row also refines its maps of each real photo: a row of the real-photo table,
    a note that this re-rendering is what refinement optimises, and a figure in results/MLflow."""
    from svbrdf_bench.report import REAL_REFINED_CAVEAT

    out, result, _ = refined_real
    table = _section(result.stdout, "Real photos")
    assert [line.split("  ")[0] for line in table[3:]] == [LABEL, REFINED]
    assert all(line.split()[-5] == "2" for line in table[3:])  # two photos each
    assert REAL_REFINED_CAVEAT in result.stdout
    md = (out / "report.md").read_text()
    assert f"| {REFINED} | 2 |" in md and REAL_REFINED_CAVEAT in md
    records = _records(out)
    before, after = (records[x]["real_rerender_rmse_median"] for x in (LABEL, REFINED))
    assert 0 <= after < 1 and 0 <= before < 1
    assert after < before  # by construction: refinement optimised the re-rendering of these photos
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    metrics = {k: c.data.metrics for k, c in _children(parent).items()}
    assert metrics[REFINED]["real/rerender_rmse_median"] == pytest.approx(after)
    assert "test/real/rerender_rmse" not in metrics[REFINED]  # kept out of the test means


def test_the_real_photo_sheet_puts_each_refined_row_under_its_model(refined_real):
    out, _, sheets = refined_real
    ((labels, columns),) = [(rows, c) for path, rows, c in sheets if path.endswith("real_comparison.png")]
    names = ("fold0 (reference)", f"fold0 +refine {STEPS} (reference)")  # each refined row under its model's
    assert labels == [f"#{i} {x}" for i in range(2) for x in names]
    assert columns == ["photo", "normal", "diffuse", "roughness", "specular", "fitted flash"]
    image = read_image(out / "real_comparison.png")
    assert image.shape[0] == 3 and image.shape[1] >= 4 * 96  # four rows of enlarged tiles
    assert "(real_comparison.png)" in (out / "report.md").read_text()


def test_without_real_data_no_real_sheet(refined):
    out, result, _ = refined
    assert not (out / "real_comparison.png").exists()
    assert "Real photos" not in result.stdout and "real_comparison" not in (out / "report.md").read_text()


@pytest.mark.parametrize(
    ("value", "needle"),
    [("-5", "-5 is negative"), ("0,-50", "-50 is negative"), ("1.5", "'1.5' is not a whole number"),
     ("fifty", "'fifty' is not a whole number"), ("", "--refine is empty"), (" ", "--refine is empty"),
     ("0,,50", "an empty budget"), ("50,", "an empty budget")],
)  # fmt: skip
def test_bad_refine_values_are_one_line_exit_2(value, needle, tmp_path):
    result = _invoke("run", "--models", "ours", "--refine", value, "-o", tmp_path / "r")
    assert result.exit_code == 2, result.output
    (err,) = _errors(result)
    assert err.startswith("svbrdf-bench: error: --refine") and needle in err and "--refine 0,50,200" in err
    assert not (tmp_path / "r").exists()  # refused before anything


@pytest.mark.parametrize("flags", [["--refine-flash", "0"], ["--refine-flash", "sideways"],
                                   ["--refine-flash", "nan"]])  # fmt: skip
def test_bad_refine_flash_is_one_line_exit_2(flags, tmp_path):
    result = _invoke("run", "--models", "ours", "--refine", "0,5", *flags, "-o", tmp_path / "r")
    assert result.exit_code == 2, result.output
    (err,) = _errors(result)
    assert err.startswith("svbrdf-bench: error: --refine-flash")


def test_budgets_parse_sorted_without_repeats_and_with_0():
    assert parse_budgets("0") == (0,)
    assert parse_budgets("200, 50,50") == (0, 50, 200)
    assert parse_flash("axis") == "axis" and parse_flash("15") == 15.0
    with pytest.raises(BenchError):
        parse_budgets(None)


@pytest.mark.slow
def test_a_trained_fit_refined(tmp_path):
    """A fit's row (the fit's own run is not the child: --from-runs) refined: the refined row keeps
    the fit's training figures in the time table and its clock, and stays out of the cost pairs."""
    from click.testing import CliRunner

    from svbrdf_bench.report import build_report
    from svbrdf_train.cli import cli as train_cli

    fit = CliRunner().invoke(
        train_cli,
        ["fit", "-q", "--recipe", "ours", "--size", "smoke", "--out", str(tmp_path / "fit"), "--set",
         "train.max_steps=2", "--experiment", "tests-bench-refine", "--run-name", "ours-refined"],
        catch_exceptions=False,
    )  # fmt: skip
    assert fit.exit_code == 0, fit.output
    run_id = json.loads((tmp_path / "fit" / "last.json").read_text())["run_id"]
    result = _invoke(
        "run", "--from-runs", run_id, *FAST, "--refine", "3", "--no-baselines", "-o", tmp_path / "r"
    )
    assert result.exit_code == 0, result.output
    parent = json.loads((tmp_path / "r" / "results.json").read_text())["parent_run"]
    report = build_report(parent)
    assert [e.label for e in report.models] == ["ours", "ours +refine 3"]
    base, refined_row = report.models
    assert (
        refined_row.refine_steps == 3 and refined_row.base_label == "ours" and refined_row.clock == base.clock
    )
    assert refined_row.figures["time/train_s"] == base.figures["time/train_s"]
    assert report.costed == [base] and report.competitors == [base]
    assert np.isfinite(refined_row.per_sample["rmse/render"]).all()
    assert _section(result.stdout, "Time and memory")[4].startswith("ours +refine 3")
