"""A fit keeps the weights of its best validation (``train.keep_best``, ``fit --keep-best``), so
that a long fit that overfits ships its best step, and a resumed fit goes on from the best
it recorded instead of forgetting it."""

from __future__ import annotations

import pytest
import torch
from click.testing import CliRunner

from svbrdf_train.cli import cli
from svbrdf_train.errors import RecipeError
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training import validation
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.trainer import FitOptions, fit


@pytest.fixture
def scripted(monkeypatch):
    """Validation that reports ``val/rmse/render`` from a list, one value per call (and records
    the generator's first weight each time, to tell which step's weights were kept)."""
    values: list[float] = []
    seen: list[tuple[float, torch.Tensor]] = []
    real = validation.Validator.__call__

    def call(self, g):
        metrics, grid = real(self, g)
        metrics["val/rmse/render"] = values.pop(0)
        first = next(iter(g.state_dict().values())).detach().clone()
        seen.append((metrics["val/rmse/render"], first))
        return metrics, grid

    monkeypatch.setattr(validation.Validator, "__call__", call)
    return values, seen


def _recipe(steps: int):
    return load_recipe(
        "ours", "smoke", {"train.max_steps": steps, "train.epochs": 100, "train.validate_every": 1,
                          "train.keep_best": "val/rmse/render"},
    )  # fmt: skip


def test_the_best_validation_is_kept_not_the_last(tmp_path, scripted):
    values, seen = scripted
    values[:] = [0.5, 0.3, 0.4, 0.6]
    result = fit(_recipe(4), FitOptions(out=tmp_path / "fit", progress=False, track=False))
    assert result.status == "FINISHED" and result.step == 4
    assert result.best == {"metric": "val/rmse/render", "value": pytest.approx(0.3), "step": 2}
    best = load_checkpoint(tmp_path / "fit" / "best.pt")
    last = load_checkpoint(tmp_path / "fit" / "last.pt")
    assert best["step"] == 2 and last["step"] == 4
    assert best["best"]["step"] == 2
    first = next(iter(best["generator"].values()))
    assert torch.equal(first, seen[1][1])  # the weights validated at step 2
    assert not torch.equal(first, next(iter(last["generator"].values())))
    assert "optimizers" not in best and "rng" not in best  # the weights alone, as weights.pt


def test_a_resumed_fit_goes_on_from_the_best_it_recorded(tmp_path, scripted):
    values, _ = scripted
    out = tmp_path / "fit"
    values[:] = [0.5, 0.2]
    fit(_recipe(2), FitOptions(out=out, progress=False, track=False))
    values[:] = [0.4, 0.3]  # worse than step 2's 0.2: best.pt stays
    result = fit(None, FitOptions(out=out, resume=True, progress=False, track=False,
                                  overrides={"train.max_steps": 4}))  # fmt: skip
    assert result.step == 4 and result.best["step"] == 2
    assert load_checkpoint(out / "best.pt")["best"]["value"] == pytest.approx(0.2)


def test_a_new_fit_over_an_old_folder_does_not_keep_the_old_best(tmp_path, scripted):
    values, _ = scripted
    out = tmp_path / "fit"
    values[:] = [0.1]
    fit(_recipe(1), FitOptions(out=out, progress=False, track=False))
    values[:] = [0.7, 0.8]
    result = fit(_recipe(2), FitOptions(out=out, force=True, progress=False, track=False))
    assert result.best["step"] == 1 and result.best["value"] == pytest.approx(0.7)


def test_the_best_is_recorded_in_mlflow(tmp_path, scripted, monkeypatch):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    values, _ = scripted
    values[:] = [0.5, 0.3, 0.4]
    result = fit(_recipe(3), FitOptions(out=tmp_path / "fit", progress=False, experiment="tests-best"))
    client = MlflowClient(uri)
    steps = [(m.step, m.value) for m in client.get_metric_history(result.run_id, "best/step")]
    assert sorted(steps) == [(1, 1.0), (2, 2.0)]
    run = client.get_run(result.run_id)
    assert run.data.tags["svbrdf.best_step"] == "2"
    assert run.data.tags["svbrdf.best_metric"] == "val/rmse/render"
    names = [a.path for a in client.list_artifacts(result.run_id, "checkpoints")]
    assert "checkpoints/best.pt" in names


def test_a_fold_metric_needs_a_fold():
    with pytest.raises(RecipeError, match="keep_best is val_fold/rmse/render but no materials source holds out a fold"):
        load_recipe("ours", "smoke", {"train.keep_best": "val_fold/rmse/render"})


def test_the_watched_real_set_is_never_chosen_on():
    with pytest.raises(RecipeError, match="keep_best"):
        load_recipe("ours", "smoke", {"train.keep_best": "val_real/rmse/render"})
    result = CliRunner().invoke(cli, ["fit", "--recipe", "ours", "--size", "smoke", "--keep-best", "val_real/rmse/render"])
    assert result.exit_code == 2 and "val_real/rmse/render" in result.output and "Traceback" not in result.output
