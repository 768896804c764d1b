"""Real materials beside synthetic ones: validation on a Des18 folder, the field of view of
Des18 training crops, and the clock that budgets training time."""

from __future__ import annotations

import time

import pytest
import torch
from click.testing import CliRunner

from conftest import des18_strips as _strips
from svbrdf_train.cli import cli
from svbrdf_train.data import Des18Folder
from svbrdf_train.data.fitdata import build_datasets, real_validation_set
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.clock import CLOCK_TAG, TrainClock
from svbrdf_train.training.trainer import FitOptions, fit

MAPS = ("normal", "diffuse", "roughness", "specular", "render")


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def test_a_tiny_fit_with_a_des18_folder_logs_val_real_metrics(tmp_path):
    real = _strips(tmp_path / "real", count=3)
    recipe = load_recipe("ours", "smoke", {"data.real_validation": str(real)})
    result = fit(recipe, FitOptions(out=tmp_path / "out", progress=False, experiment="tests-real-val"))
    assert result.status == "FINISHED", result.message
    run = _client().get_run(result.run_id)
    metrics = run.data.metrics
    for name in MAPS:
        assert 0 <= metrics[f"val_real/rmse/{name}"] < 1, name
        assert f"val/rmse/{name}" in metrics
    # Logged at every validation step, beside the training time the curves are drawn against.
    history = _client().get_metric_history(result.run_id, "val_real/rmse/render")
    seconds = _client().get_metric_history(result.run_id, "val/train_seconds")
    assert {m.step for m in history} == {m.step for m in seconds}
    # The real set differs from the procedural one, so the figures do too.
    assert metrics["val_real/rmse/diffuse"] != metrics["val/rmse/diffuse"]
    assert run.data.tags[CLOCK_TAG] == "cpu"
    assert metrics["train/total_wall_seconds"] > 0


def test_val_real_is_the_generator_scored_on_the_resized_folder(tmp_path):
    """The logged figure is the RMSE of the final generator on the whole tiles brought to the
    training resolution: recompute it from the checkpoint."""
    from torch.utils.data import DataLoader

    from svbrdf_render import SVBRDF
    from svbrdf_render.compare import map_rmse
    from svbrdf_train.inference import load_generator

    real = _strips(tmp_path / "real", count=2)
    recipe = load_recipe("ours", "smoke", {"data.real_validation": str(real)})
    result = fit(recipe, FitOptions(out=tmp_path / "out", progress=False, track=False))
    g, _ = load_generator(load_checkpoint(result.checkpoint))
    data, _ = real_validation_set(str(real), recipe.train.resolution)
    batch = next(iter(DataLoader(data, batch_size=8)))
    assert batch["input"].shape[-1] == recipe.train.resolution
    with torch.no_grad():
        pred = g(batch["input"])
    diffuse = float(map_rmse(pred, SVBRDF.unpack(batch["maps"]))["diffuse"].mean())
    assert result.metrics["val_real/rmse/diffuse"] == pytest.approx(diffuse, rel=1e-4, abs=1e-6)


def test_real_validation_resizes_whole_tiles(tmp_path):
    real = _strips(tmp_path / "real", count=1, size=64)
    data, what = real_validation_set(str(real), 32)
    sample = data[0]
    assert sample["input"].shape == (3, 32, 32) and sample["maps"].shape == (10, 32, 32)
    whole = Des18Folder(real, "test", crop=None)[0]
    # Area filter: each output pixel is the mean of the 2x2 input pixels it covers.
    expected = whole["input"].reshape(3, 32, 2, 32, 2).mean(dim=(2, 4))
    assert torch.allclose(sample["input"], expected, atol=1e-6)
    normal = sample["maps"][:3]  # packed maps hold the unit vectors themselves
    assert torch.allclose(normal.norm(dim=0), torch.ones(32, 32), atol=1e-3)
    assert what.startswith("1 Des18 samples of") and "resized whole to 32 px" in what


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda p: p / "nowhere", "no such file or folder"),
        (lambda p: (p / "empty").mkdir() or p / "empty", "no Des18 strips"),
        (lambda p: _photos(p / "photos"), "cannot be read as materials with ground truth"),
        (lambda p: _file(p / "a.txt"), "not a Des18 folder nor .h5 shards"),
    ],
    ids=["missing", "empty", "photos-without-maps", "a-file"],
)
def test_bad_real_validation_is_one_line_naming_it(tmp_path, make, needle):
    path = make(tmp_path)
    result = CliRunner().invoke(
        cli,
        ["fit", "-q", "--no-track", "--recipe", "ours", "--size", "smoke", "--out", str(tmp_path / "out"),
         "--set", f"data.real_validation={path}"],
        catch_exceptions=False,
    )  # fmt: skip
    assert result.exit_code == 2, result.output
    err = result.stderr
    assert err.startswith("svbrdf-train: error: ") and err.count("\n") == 1, err
    assert str(path) in err and needle in err, err
    assert not (tmp_path / "out" / "last.pt").exists()


def _file(path):
    path.write_text("not a data set")
    return path


def _photos(folder):
    from svbrdf_render import write_image

    folder.mkdir()
    write_image(folder / "photo.png", torch.rand(3, 40, 40))
    return folder


def test_des18_training_crops_cover_the_share_of_the_surface_des18_crops_do(tmp_path):
    """At 128 px a 288-px tile is scaled to 144 before its random 128 crop: the window covers
    128/144 = 256/288 of the surface, as Des18's own crops at 256 px; validation tiles are whole."""
    folder = _strips(tmp_path / "d", count=3, size=288)
    recipe = load_recipe(
        "ours", "smoke", {"data.source": "des18", "data.path": str(folder), "data.validation": 1,
                          "train.resolution": 128}
    )  # fmt: skip
    train, val = build_datasets(recipe)
    base = train.dataset if hasattr(train, "dataset") else train
    assert base.fov == "resize"
    top, left, _ = base.placement(0, 144)
    assert 0 <= top <= 16 and 0 <= left <= 16
    assert train[0]["input"].shape == (3, 128, 128)
    whole = Des18Folder(folder, "test", crop=None)[2]["input"]
    expected = torch.nn.functional.interpolate(whole[None], size=(128, 128), mode="area")[0]
    assert torch.allclose(val[0]["input"], expected, atol=1e-6)


def test_cpu_clock_counts_process_time_not_waiting():
    clock = TrainClock("auto", torch.device("cpu"))
    assert clock.name == "cpu"
    start = clock.now()
    time.sleep(0.3)  # waiting is not computing: a busy machine cannot eat the budget this way
    slept = clock.now() - start
    x = torch.rand(400, 400)
    t0 = clock.now()
    for _ in range(30):
        x = (x @ x).clamp(-1, 1)
    worked = clock.now() - t0
    assert slept < 0.05
    assert worked > 0
    assert TrainClock("wall", torch.device("cpu")).name == "wall"
    with pytest.raises(ValueError, match="train.clock"):
        TrainClock("sundial", torch.device("cpu"))
