"""A fit saves its weights at training budgets (``train.snapshot_minutes``, ``snapshot_steps``),
so that one fit gives its model at 2, 8 and 32 minutes instead of a fit per budget."""

from __future__ import annotations

import pytest
import torch

from svbrdf_train.errors import RecipeError
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.trainer import FitOptions, fit


def _recipe(steps: int, **train):
    sets = {"train.max_steps": steps, "train.epochs": 100, "train.validate_every": 1000}
    return load_recipe("ours", "smoke", {**sets, **{f"train.{k}": v for k, v in train.items()}})


def _first(state) -> torch.Tensor:
    return next(iter(state["generator"].values()))


def test_the_weights_are_saved_when_each_step_mark_is_reached(tmp_path):
    out = tmp_path / "fit"
    fit(_recipe(4, snapshot_steps=[1, 3, 50]), FitOptions(out=out, progress=False, track=False))
    one, three = (load_checkpoint(out / "snapshots" / f"steps-{n}.pt") for n in (1, 3))
    assert one["step"] == 1 and three["step"] == 3
    assert one["snapshot"]["kind"] == "steps" and one["snapshot"]["mark"] == 1
    assert not (out / "snapshots" / "steps-50.pt").exists()  # never reached
    assert not torch.equal(_first(one), _first(three))
    assert "optimizers" not in one  # the weights alone


def test_minute_marks_follow_the_training_clock(tmp_path):
    out = tmp_path / "fit"
    fit(_recipe(2, snapshot_minutes=[1e-9, 1e6]), FitOptions(out=out, progress=False, track=False))
    taken = sorted(p.name for p in (out / "snapshots").glob("*.pt"))
    assert taken == ["minutes-1e-09.pt"]
    snap = load_checkpoint(out / "snapshots" / "minutes-1e-09.pt")["snapshot"]
    assert snap["step"] == 1 and snap["seconds"] >= 1e-9 * 60


def test_a_resumed_fit_takes_only_the_marks_it_has_not_passed(tmp_path):
    out = tmp_path / "fit"
    fit(_recipe(2, snapshot_steps=[1, 3]), FitOptions(out=out, progress=False, track=False))
    before = (out / "snapshots" / "steps-1.pt").read_bytes()
    result = fit(None, FitOptions(out=out, resume=True, progress=False, track=False,
                                  overrides={"train.max_steps": 4}))  # fmt: skip
    assert result.step == 4
    assert (out / "snapshots" / "steps-1.pt").read_bytes() == before
    assert load_checkpoint(out / "snapshots" / "steps-3.pt")["step"] == 3


def test_snapshots_go_to_mlflow(tmp_path, monkeypatch):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    result = fit(_recipe(2, snapshot_steps=[2]), FitOptions(out=tmp_path / "fit", progress=False,
                                                             experiment="tests-snapshots"))  # fmt: skip
    client = MlflowClient(uri)
    assert "snapshots/steps-2.pt" in [a.path for a in client.list_artifacts(result.run_id, "snapshots")]
    assert [m.value for m in client.get_metric_history(result.run_id, "snapshot/steps-2")] == [2.0]


@pytest.mark.parametrize("field,value", [("snapshot_steps", [0]), ("snapshot_steps", [1.5]),
                                          ("snapshot_minutes", [-1.0]), ("snapshot_minutes", [])])
def test_bad_marks_are_refused_naming_the_field(field, value):
    with pytest.raises(RecipeError, match=field):
        load_recipe("ours", "smoke", {f"train.{field}": value})
