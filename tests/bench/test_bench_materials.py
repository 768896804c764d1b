"""The benchmark averages a folder of strips per source material, not per strip."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from conftest import random_svbrdf
from svbrdf_bench.cli import cli
from svbrdf_bench.errors import BenchError
from svbrdf_bench.report import COLUMNS, ModelEntry, Report, averaging_note, terminal
from svbrdf_bench.testset import test_set as make_test_set
from svbrdf_render import write_des18

# Material a is shown by 3 strips, b by 1.
GROUPS = [("a",), ("a",), ("a",), ("b",)]


def _entry(label, values, baseline=False):
    per_sample = {f"rmse/{c}": np.asarray(values, dtype=np.float64) for c in COLUMNS}
    return ModelEntry(label, f"run-{label}", f"run-{label}", per_sample, {}, baseline=baseline)


def _report(groups=GROUPS):
    models = [_entry("model", [0.1, 0.1, 0.1, 0.5]), _entry("mean", [0.2, 0.2, 0.2, 0.6], baseline=True)]
    return Report("parent", "quick", "4 Des18 samples", "LPIPS skipped", "2 min", models, groups=groups,
                  sample_names=[f"s{i}" for i in range(4)], group_by="file")  # fmt: skip


def test_a_material_with_three_strips_weighs_as_much_as_one_with_one():
    report = _report()
    mean, low, high = report.interval(report.models[0], "rmse", "render")
    assert mean == pytest.approx(0.3)  # (0.1 + 0.5) / 2; per strip it would be 0.2
    assert low <= mean <= high
    (row,) = [r for r in report.against_reference() if r["column"] == "render"]
    assert row["rmse_difference"] == pytest.approx(-0.1) and row["relative"] == pytest.approx(-0.1 / 0.4)
    assert "4 strips of 2 materials" in averaging_note(report)
    text = terminal(report)
    assert "mean over materials; 95% bootstrap interval over materials" in text
    assert "0.3000" in text
    per_strip = report.per_strip_json()
    assert per_strip["rows"]["model"]["rmse/render"] == [0.1, 0.1, 0.1, 0.5]
    assert per_strip["per_material"]["model"]["strips"] == {"a": 3, "b": 1}


def test_without_groups_the_tables_stay_per_image():
    report = _report(groups=None)
    assert report.interval(report.models[0], "rmse", "render")[0] == pytest.approx(0.2)
    assert "over test images" in terminal(report) and "4 test images" in averaging_note(report)


def _folder(tmp_path, names):
    folder = tmp_path / "strips"
    folder.mkdir()
    for i, name in enumerate(names):
        write_des18(folder / name, torch.rand(1, 3, 16, 16), random_svbrdf(1, 16, seed=i))
    return folder


def test_the_test_set_groups_des18_names_and_falls_back_to_files(tmp_path):
    folder = _folder(tmp_path, ["0000004;aXb;0X1.png", "0000008;bXc;1X0.png"])
    test = make_test_set(folder, 16, 1)
    assert test.group_by == "des18" and test.groups == [("a", "b"), ("b", "c")]
    assert test.sample_names == ["0000004;aXb;0X1.png", "0000008;bXc;1X0.png"]
    assert make_test_set(folder, 16, 1, "file").groups == [("0000004;aXb;0X1",), ("0000008;bXc;1X0",)]
    assert make_test_set(None, 16, 2).groups is None  # procedural: each image its own
    with pytest.raises(BenchError, match="--group-by des18"):
        make_test_set(None, 16, 2, "des18")


def test_group_by_des18_on_other_names_is_one_line_exit_2(tmp_path):
    folder = _folder(tmp_path, ["0000004;aXb;0X1.png", "ambientcg_Bark014.png"])
    assert make_test_set(folder, 16, 1).group_by == "file"  # auto: one name does not parse
    result = CliRunner().invoke(cli, ["run", "--models", "ours", "--size", "smoke", "--test-data", str(folder),
                                      "--group-by", "des18"])  # fmt: skip
    assert result.exit_code == 2, result.output
    err = "\n".join(line for line in result.stderr.splitlines() if " INFO mlflow." not in line)
    assert err.startswith("svbrdf-bench: error: --test-data") and err.strip().count("\n") == 0, err
    assert "ambientcg_Bark014.png: not a Des18 strip name" in err
