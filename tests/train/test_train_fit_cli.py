"""``svbrdf-train fit`` refuses what cannot work, before training, in one line with exit code 2."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from svbrdf_train.cli import cli


def _fit(tmp_path, *args):
    result = CliRunner().invoke(
        cli, ["fit", "-q", "--no-track", "--out", str(tmp_path / "out"), *args], catch_exceptions=False
    )
    return result


def _assert_refused(result, *needles):
    assert result.exit_code == 2, result.output
    err = result.stderr
    assert err.startswith("svbrdf-train: error: ") and err.count("\n") == 1, err
    for needle in needles:
        assert needle in err, (needle, err)


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--recipe", "ourz", "--size", "smoke"], ["unknown recipe 'ourz'", "'ours'"]),
        (["--recipe", "ours", "--size", "smoke", "--set", "loss.advv=1"], ["'advv'", "'adv'", "ours.yaml"]),
        (
            ["--recipe", "ours", "--size", "smoke", "--set", "trian.batch=1"],
            ["unknown section 'trian'", "'train'"],
        ),
        (["--recipe", "ours", "--size", "smoke", "--set", "train.batch=two"], ["'batch'", "int"]),
        (["--recipe", "ours", "--size", "smoke", "--set", "loss"], ["section.field=value"]),
        (["--size", "smoke"], ["--recipe is required"]),
        (
            ["--recipe", "ours", "--size", "smoke", "--data", "/no/such/place"],
            ["/no/such/place", "no such file"],
        ),
        (
            ["--recipe", "ours", "--size", "smoke", "--set", "train.renderings=6"],
            ["discriminator.config.renderings is 9 but train.renderings is 6"],
        ),
        (
            ["--recipe", "ours", "--size", "smoke", "--set", "data.count=1"],
            ["data.count is 1, fewer samples per epoch than one step of train.batch 2"],
        ),
        (["--recipe", "ours", "--size", "smoke", "--device", "tpu"], ["--device 'tpu'"]),
        (["--recipe", "ours", "--size", "smoke", "--resume"], ["nothing to resume"]),
    ],
)
def test_bad_settings_are_refused_with_one_line(tmp_path, args, needles):
    _assert_refused(_fit(tmp_path, *args), *needles)
    assert not (tmp_path / "out" / "last.pt").exists()


@pytest.fixture
def finished(tmp_path):
    result = _fit(tmp_path, "--recipe", "ours", "--size", "smoke")
    assert result.exit_code == 0, result.output
    return tmp_path


def test_an_existing_checkpoint_is_never_overwritten_silently(finished):
    before = (finished / "out" / "last.pt").read_bytes()
    _assert_refused(_fit(finished, "--recipe", "ours", "--size", "smoke"), "--resume", "--force")
    assert (finished / "out" / "last.pt").read_bytes() == before
    assert _fit(finished, "--recipe", "ours", "--size", "smoke", "--force").exit_code == 0


def test_resume_refuses_a_different_recipe_and_names_the_field(finished):
    _assert_refused(
        _fit(finished, "--recipe", "ours", "--size", "smoke", "--resume", "--set", "loss.adv=0.2"),
        "loss.adv: 0.1 -> 0.2",
    )


def test_resume_without_recipe_takes_the_checkpoint_s_and_a_new_budget(finished):
    result = _fit(finished, "--resume", "--max-steps", "3")
    assert result.exit_code == 0, result.output
    assert "resuming ours (smoke) at step 2" in result.stderr
    assert "3 steps" in result.stdout


def test_the_experiment_is_the_flag_else_mlflow_experiment_name_else_svbrdf(monkeypatch):
    from svbrdf_train.commands.fit import fit

    def chosen(*args):
        return fit.make_context("fit", ["--recipe", "ours", *args]).params["experiment"]

    assert chosen() == "svbrdf"
    monkeypatch.setenv("MLFLOW_EXPERIMENT_NAME", "from-the-environment")
    assert chosen() == "from-the-environment"
    assert chosen("--experiment", "from-the-flag") == "from-the-flag"
    assert "MLFLOW_EXPERIMENT_NAME" in CliRunner().invoke(cli, ["fit", "--help"]).output


def test_a_fit_logs_to_the_experiment_mlflow_experiment_name_names(tmp_path):
    import json

    from mlflow import MlflowClient

    result = CliRunner(env={"MLFLOW_EXPERIMENT_NAME": "tests-env-experiment"}).invoke(
        cli, ["fit", "-q", "--recipe", "radn", "--size", "smoke", "--out", str(tmp_path / "out")],
        catch_exceptions=False,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    client = MlflowClient()
    run = client.get_run(json.loads((tmp_path / "out" / "last.json").read_text())["run_id"])
    experiment = client.get_experiment(run.info.experiment_id)
    assert experiment.name == "tests-env-experiment"
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"  # the training view


def test_help_teaches_with_examples():
    result = CliRunner().invoke(cli, ["fit", "--help"])
    assert result.exit_code == 0
    for needle in ("--resume", "--max-minutes", "--set", "torchrun", "Exit status"):
        assert needle in result.output


def test_recipes_lists_and_resolves(tmp_path):
    listed = CliRunner().invoke(cli, ["recipes"])
    assert listed.exit_code == 0
    for name in ("ours", "no-attn", "no-attn-wide", "no-adv", "no-svbrdf", "multigan", "radn"):
        assert any(line.startswith(name + " ") for line in listed.output.splitlines()), name
    import yaml

    shown = CliRunner().invoke(cli, ["recipes", "radn", "--size", "cpu", "--set", "train.batch=3"])
    assert shown.exit_code == 0
    resolved = yaml.safe_load(shown.output)
    assert resolved["discriminator"] is None and resolved["loss"]["render"] == 1.0
    assert resolved["train"]["batch"] == 3 and resolved["train"]["resolution"] == 128


@pytest.mark.slow
def test_an_untracked_fit_finishes_where_mlflow_is_not_installed(tmp_path, monkeypatch):
    """``--no-track`` on a machine without mlflow (a GPU box with torch alone): the fit trains,
    saves and ends with exit 0. It used to fail at its very end, importing mlflow to log the
    finished generator as a model of a run that did not exist."""
    import sys

    monkeypatch.setitem(sys.modules, "mlflow", None)  # `import mlflow` raises ImportError
    result = _fit(tmp_path, "--recipe", "ours", "--size", "smoke", "--max-steps", "2")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "last.pt").is_file()
