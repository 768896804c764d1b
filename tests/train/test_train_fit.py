"""The trainer in one process: every recipe fits, the loss goes down, MLflow gets the whole run.

Runs go to the suite's temporary MLflow store (tests/conftest.py).
"""

from __future__ import annotations

import math

import pytest
import torch
import yaml

from svbrdf_train.recipe import list_recipes, load_recipe
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.trainer import FitOptions, fit

BUILT_IN = ("ours", "no-attn", "no-attn-wide", "no-adv", "no-svbrdf", "multigan", "radn")


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def _fit(tmp_path, name="ours", size="smoke", **overrides):
    recipe = load_recipe(name, size, overrides)
    return fit(recipe, FitOptions(out=tmp_path / name, progress=False, experiment="tests-fit")), recipe


def test_every_built_in_recipe_is_registered():
    assert set(BUILT_IN) <= set(list_recipes())


@pytest.mark.parametrize("name", BUILT_IN)
def test_two_step_fit_of_every_recipe(tmp_path, name):
    """Each recipe trains 2 steps at the smoke size, logs the terms it has, and no others."""
    result, recipe = _fit(tmp_path, name)
    assert result.status == "FINISHED", result.message
    assert result.step == 2 and result.exit_code == 0
    state = load_checkpoint(result.checkpoint)
    assert state["step"] == 2
    assert (state["discriminator"] is None) == (recipe.loss.adv == 0)
    for tensor in state["generator"].values():
        assert torch.isfinite(tensor).all()
    run = _client().get_run(result.run_id)
    assert run.info.status == "FINISHED"
    metrics = run.data.metrics
    for term, weight in (
        ("adv", recipe.loss.adv),
        ("render", recipe.loss.render),
        ("svbrdf", recipe.loss.svbrdf),
    ):
        assert (f"train/{term}" in metrics) == (weight > 0), term
    assert ("train/d_loss" in metrics) == (recipe.discriminator is not None)
    for name_ in ("normal", "diffuse", "roughness", "specular", "render"):
        assert 0 <= metrics[f"val/rmse/{name_}"] < 1


def test_loss_decreases_on_a_fixed_tiny_set(tmp_path):
    """40 steps on 4 materials: the rendering and map losses fall clearly below where they start."""
    result, _ = _fit(
        tmp_path,
        **{
            "data.count": 4,
            "train.epochs": 20,
            "train.max_steps": 40,
            "train.validate_every": 40,
            "train.checkpoint_every": 40,
            "optim.lr": 2e-3,
            "optim.d_lr": 2e-3,
        },
    )
    assert result.status == "FINISHED" and result.step == 40
    client = _client()
    for term in ("render", "svbrdf"):
        values = [
            m.value
            for m in sorted(client.get_metric_history(result.run_id, f"train/{term}"), key=lambda m: m.step)
        ]
        assert len(values) == 40
        first, last = sum(values[:5]) / 5, sum(values[-5:]) / 5
        assert last < 0.85 * first, (term, first, last)


def test_mlflow_run_holds_config_tags_metrics_and_artifacts(tmp_path):
    result, recipe = _fit(tmp_path, "ours")
    client = _client()
    run = client.get_run(result.run_id)
    params, tags = run.data.params, run.data.tags
    # params: the whole resolved recipe, and the networks' complete configs
    assert params["loss.adv"] == "0.1" and params["loss.render"] == "0.5" and params["loss.svbrdf"] == "0.5"
    assert params["loss.maps.roughness"] == "0.5"
    assert params["generator.name"] == "ours" and params["discriminator.name"] == "patchgan"
    assert params["train.resolution"] == str(recipe.train.resolution)
    assert params["generator.resolved.depth"] == "4"  # the tiny preset, resolved
    assert int(params["parameters.generator"]) > 0
    # tags: code, versions, machine, seed, recipe
    assert tags["recipe"] == "ours" and tags["recipe.size"] == "smoke"
    assert tags["seed"] == str(recipe.train.seed) and tags["device"] == "cpu"
    assert tags["git_sha"] and tags["version.torch"] == torch.__version__
    assert tags["version.svbrdf-train"] != "not installed"
    # metrics per step (log_every 1 at the smoke size)
    history = client.get_metric_history(result.run_id, "train/loss")
    assert sorted(m.step for m in history) == [1, 2]
    assert all(math.isfinite(m.value) for m in history)
    assert {m.key for m in client.get_metric_history(result.run_id, "val/rmse/render")} == {"val/rmse/render"}
    # artifacts: the config as YAML, sample grids, the weights
    listed = {
        a.path
        for folder in ("config", "samples", "checkpoints")
        for a in client.list_artifacts(result.run_id, folder)
    }
    assert {"config/recipe.yaml", "samples/step_0000002.png", "checkpoints/weights.pt"} <= listed
    local = client.download_artifacts(result.run_id, "config/recipe.yaml", str(tmp_path))
    assert yaml.safe_load(open(local)) == recipe.to_dict()


def test_sample_grids_are_an_image_series_with_their_steps(tmp_path):
    """Each validation's grid is logged with its step (MLflow's log_image key/step), which the UI
    shows with a step slider, and the logged image is the grid written to --out."""
    import re

    import numpy as np
    from PIL import Image

    result, _ = _fit(tmp_path, "radn", **{"train.validate_every": 1})
    assert result.status == "FINISHED" and result.step == 2
    client = _client()
    pngs = {}
    for a in client.list_artifacts(result.run_id, "images"):
        found = re.fullmatch(r"samples[+%]step[+%](\d+)[+%].*\.png", a.path.split("/")[-1])
        if found:
            pngs[int(found[1])] = a.path
    assert sorted(pngs) == [1, 2]
    assert client.get_run(result.run_id).data.tags["mlflow.loggedImages"].lower() == "true"
    logged = np.asarray(Image.open(client.download_artifacts(result.run_id, pngs[2], str(tmp_path))))
    written = np.asarray(Image.open(tmp_path / "radn" / "samples" / "step_0000002.png"))
    assert logged.shape == written.shape and (logged == written).all()


def test_experiments_made_here_open_in_the_model_training_view():
    """MLflow 3's UI opens an experiment in its GenAI or its model-training view after the kind tag."""
    from svbrdf_train.tracking import MlflowTracker

    assert _client().get_experiment_by_name("tests-kind") is None
    MlflowTracker(experiment="tests-kind", run_name="kind").finish("FINISHED")
    tags = _client().get_experiment_by_name("tests-kind").tags
    assert tags["mlflow.experimentKind"] == "custom_model_development"


def test_time_budget_stops_the_fit_and_says_so(tmp_path):
    result, _ = _fit(tmp_path, **{"train.max_steps": None, "train.epochs": 1000, "train.max_minutes": 0.0})
    assert result.status == "FINISHED"
    assert result.step == 1  # the budget is checked after each step
    assert "time budget" in result.message
    assert _client().get_run(result.run_id).data.tags["svbrdf.stop"] == result.message


def test_without_tracking_nothing_reaches_mlflow(tmp_path):
    recipe = load_recipe("radn", "smoke")
    result = fit(
        recipe, FitOptions(out=tmp_path / "r", progress=False, track=False, experiment="tests-untracked")
    )
    assert result.status == "FINISHED" and result.run_id is None
    assert _client().get_experiment_by_name("tests-untracked") is None
    assert load_checkpoint(result.checkpoint)["run_id"] is None


def test_default_store_is_mlflow_db_in_the_working_folder_with_artifacts_beside_it(tmp_path):
    """Without MLFLOW_TRACKING_URI a fit uses MLflow's default ./mlflow.db, and its artifacts go to
    ./mlartifacts next to it, not to wherever a later command happens to run."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    r = subprocess.run(
        [sys.executable, "-m", "svbrdf_train", "fit", "--recipe", "radn", "--size", "smoke", "-q"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "mlflow.db").is_file()
    saved = list((tmp_path / "mlartifacts").rglob("weights.pt"))
    assert len(saved) == 1 and saved[0].parent.name == "checkpoints"
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("svbrdf").experiment_id])
    assert run.info.status == "FINISHED" and run.data.tags["recipe"] == "radn"


def test_a_non_finite_gradient_behind_a_finite_loss_stops_before_the_step(tmp_path, monkeypatch):
    """sqrt at 0 has an infinite derivative: the loss stays finite, every gradient becomes NaN.
    The step checks the gradient norm, stops without stepping, and names the gradient."""
    import svbrdf_train.training.losses as losses  # the step's loss (loss_of(recipe.loss)) calls generator_loss

    real_loss = losses.generator_loss

    def poisoned(pred, target, **kwargs):
        total, terms = real_loss(pred, target, **kwargs)
        return total + (0.0 * pred.roughness.sum()).sqrt(), terms

    monkeypatch.setattr(losses, "generator_loss", poisoned)
    result, _ = _fit(tmp_path, "radn")
    assert result.status == "FAILED" and result.exit_code == 1
    assert result.message.startswith("non-finite generator gradient at step 1;")
    assert result.step == 0 and result.checkpoint is None
    assert _client().get_run(result.run_id).info.status == "FAILED"


def test_gradient_norms_are_logged(tmp_path):
    result, _ = _fit(tmp_path, "ours")
    metrics = _client().get_run(result.run_id).data.metrics
    assert metrics["train/grad_norm"] > 0 and math.isfinite(metrics["train/grad_norm"])
    assert metrics["train/d_grad_norm"] > 0


# -- what the MLflow UI shows of a fit: its data, its source, a view of its runs, system metrics ---


def _inputs(run) -> dict[str, list]:
    """A run's dataset inputs by context (the tag mlflow.data.context)."""
    out: dict[str, list] = {}
    for d in run.inputs.dataset_inputs:
        context = {t.key: t.value for t in d.tags}["mlflow.data.context"]
        out.setdefault(context, []).append(d.dataset)
    return out


def test_a_fit_logs_its_data_as_datasets_its_source_and_a_view_of_its_runs(tmp_path):
    """The UI's Datasets, Source and Created by of a fit: its procedural training set (the recipe's
    seed and samples per epoch) and validation set (the next seed), described, not stored; the
    command and the commit; and, a fit of its own, the experiment's saved view whose columns are
    the validation figures the fit logged."""
    import json

    from svbrdf_train.tracking import FIT_COLUMNS, FIT_VIEW, VIEW_TAG_PREFIX, git_revision

    result, recipe = _fit(tmp_path, "radn")
    client = _client()
    run = client.get_run(result.run_id)
    inputs = _inputs(run)
    assert sorted(inputs) == ["training", "validation"]
    (train,), (val,) = inputs["training"], inputs["validation"]
    d, r = recipe.data, recipe.train.resolution
    for dataset, seed, count in ((train, d.seed, d.count), (val, d.seed + 1, d.validation)):
        assert dataset.source_type == "code"
        source = json.loads(dataset.source)["tags"]
        assert (source["seed"], source["count"], source["resolution"]) == (str(seed), str(count), str(r))
        shapes = [c["tensor-spec"]["shape"] for c in json.loads(dataset.schema)["mlflow_colspec"]]
        assert shapes == [[-1, 3, r, r], [-1, 10, r, r]]
    assert train.digest != val.digest
    tags = run.data.tags
    assert tags["mlflow.source.name"] == "svbrdf-train fit" and tags["mlflow.source.type"] == "LOCAL"
    sha, _ = git_revision()
    assert tags["mlflow.source.git.commit"] == sha
    view = client.get_experiment(run.info.experiment_id).tags[VIEW_TAG_PREFIX + FIT_VIEW]
    state = json.loads(json.loads(view)["state"])
    assert state["selectedColumns"] == [f"metrics.`{c}`" for c in FIT_COLUMNS]
    assert {c for c in FIT_COLUMNS if c.startswith("val/")} <= set(run.data.metrics)


def test_the_data_of_a_fit_on_files_is_fingerprinted_by_its_files(tmp_path):
    """Training files (Des18 strips) are described by MLflow's local source and a digest of their
    names and sizes (not read: shards run to gigabytes); a real validation folder by its bytes."""
    from conftest import des18_strips
    from svbrdf_train.tracking import fit_datasets

    strips = des18_strips(tmp_path / "strips", count=2, size=32)
    real = des18_strips(tmp_path / "real", count=2, size=32)
    recipe = load_recipe("radn", "smoke", {"data.source": "des18", "data.path": str(strips),
                                           "data.real_validation": str(real)})  # fmt: skip
    (train, c1), (val, c2) = fit_datasets(recipe)
    assert (c1, c2) == ("training", "validation")
    assert train.source.to_dict()["uri"] == str(strips.resolve()) and train.name == "strips"
    first = sorted(strips.iterdir())[0]
    data = bytearray(first.read_bytes())
    data[-1] ^= 0xFF  # one byte changed, same size: the training digest (names and sizes) keeps
    first.write_bytes(bytes(data))
    (again, _), (val_again, _) = fit_datasets(recipe)
    assert again.digest == train.digest and val_again.digest == val.digest
    real_file = sorted(real.iterdir())[0]
    data = bytearray(real_file.read_bytes())
    data[-1] ^= 0xFF  # the real validation set is hashed by content
    real_file.write_bytes(bytes(data))
    (strips / "extra.png").write_bytes(b"x")  # a file more: the training digest changes
    (moved, _), (val_moved, _) = fit_datasets(recipe)
    assert moved.digest != train.digest and val_moved.digest != val.digest


def test_system_metrics_only_with_the_flag(tmp_path):
    """--system-metrics logs MLflow's system/... metrics to the fit's run; without it, none."""
    import json

    from conftest import run_cli

    common = ("--recipe", "radn", "--size", "smoke", "--experiment", "tests-system-metrics", "-q", "--force")
    env = {"MLFLOW_SYSTEM_METRICS_SAMPLING_INTERVAL": "0.2", "OMP_NUM_THREADS": "1"}
    runs = {}
    for flag in (True, False):
        out = tmp_path / str(flag)
        done = run_cli("fit", *common, "--out", str(out), *(["--system-metrics"] if flag else []), env=env)
        assert done.returncode == 0, done.stderr[-2000:]
        runs[flag] = _client().get_run(json.loads((out / "last.json").read_text())["run_id"])
    on = {k for k in runs[True].data.metrics if k.startswith("system/")}
    assert "system/cpu_utilization_percentage" in on and "system/system_memory_usage_megabytes" in on
    assert not any(k.startswith("system/") for k in runs[False].data.metrics)
