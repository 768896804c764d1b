"""The trainer in one process: every recipe fits, the loss goes down, MLflow gets the whole run.

Runs go to the suite's temporary MLflow store (tests/conftest.py).
"""

from __future__ import annotations

import math

import pytest
import torch
import yaml

from svbrdf_train.checkpoint import load_checkpoint
from svbrdf_train.recipe import list_recipes, load_recipe
from svbrdf_train.trainer import FitOptions, fit

BUILT_IN = ("ours", "no-attn", "no-adv", "no-svbrdf", "multigan", "radn")


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
    import svbrdf_train.step as step

    real_loss = step.generator_loss

    def poisoned(pred, target, **kwargs):
        total, terms = real_loss(pred, target, **kwargs)
        return total + (0.0 * pred.roughness.sum()).sqrt(), terms

    monkeypatch.setattr(step, "generator_loss", poisoned)
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
