"""Time budgets that cover the work (issue 47): a photo's ``--refine-seconds``
(``CaptureOptions.refine_seconds``), ``TrainedModel.predict(seconds=)`` and
:func:`~svbrdf_models.capture.refining.refine_prediction`'s ``seconds`` count every stage, not
the refinement's steps alone (``--refine 1 --map-size 2048 --refine-seconds 5`` took 148 s): the
stages before the steps are paid out of the budget, the steps get what is left, and none when it
cannot hold one. Each checked with one stage made slow on purpose and the budget the steps were
handed, so that no test is slow."""

from __future__ import annotations

import json
import time

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models.capture import refining
from svbrdf_models.capture.one import CaptureOptions, capture_one
from svbrdf_render import SVBRDF, Scene, render
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb

SLOW = 1.0  # seconds a stage is made to take


@pytest.fixture
def handed(monkeypatch) -> list:
    """The ``seconds`` each :func:`svbrdf_render.refine_maps` call of a refinement is handed."""
    seconds, real = [], refining.refine_maps

    def spy(*args, **kwargs):
        seconds.append(kwargs["seconds"])
        return real(*args, **kwargs)

    monkeypatch.setattr(refining, "refine_maps", spy)
    return seconds


def _photo(size: int = 64) -> torch.Tensor:
    return render(example_material("tiles", size), Scene.flash(intensity=12.0)).clamp(0, 1)


def test_the_refinement_start_is_paid_out_of_its_seconds(handed, monkeypatch):
    real = refining._start

    def slow_start(*args, **kwargs):  # the highlight and the start (8.3 s at 1024 px before issue 47)
        time.sleep(SLOW)
        return real(*args, **kwargs)

    monkeypatch.setattr(refining, "_start", slow_start)
    start = example_material("tiles", 32)
    refining.refine_prediction(_photo(), start, 3, seconds=10.0, backend="eager")
    assert 0 < handed[-1] <= 10.0 - SLOW  # the steps get what the start left
    result = refining.refine_prediction(_photo(), start, 3, seconds=SLOW / 2, backend="eager")
    assert handed[-1] == 0 and result.steps == 0  # nothing left: no step, the start's maps


def test_predict_seconds_cover_the_network(handed, monkeypatch):
    model = sm.load_model("pretrained")
    real = model._network

    def slow_network(photos):
        time.sleep(SLOW)
        return real(photos)

    monkeypatch.setattr(model, "_network", slow_network)
    maps = model.predict(_photo()[0], refine=2, seconds=10.0, backend="eager")
    assert maps.size == (64, 64)
    assert 0 < handed[-1] <= 10.0 - SLOW


class _Slow:
    """A stand-in predictor whose network takes :data:`SLOW` seconds."""

    def __init__(self, resolution: int = 64):
        self.resolution, self.source, self.sha256, self.steps = resolution, "slow:tiles", "0" * 64, 0
        self.maps = example_material("tiles", resolution)

    def predict(self, photo) -> SVBRDF:
        time.sleep(SLOW)
        return self.maps


def test_a_photos_refine_seconds_cover_its_other_stages(handed, tmp_path):
    from PIL import Image

    path = tmp_path / "photo.png"
    data = (linear_to_srgb(_photo(96)[0]) * 255).round().byte().permute(1, 2, 0).contiguous().numpy()
    Image.fromarray(data).save(path)
    after = 96 * 96 * refining.AFTER_REFINE_SECONDS_PER_PIXEL  # the stages after the steps, kept back
    capture_one(_Slow(), path, tmp_path / "a", CaptureOptions(refine=3, refine_seconds=10.0, relit="none"))
    assert 0 < handed[-1] <= 10.0 - SLOW - after  # the network's time, and what follows, came out of it
    short = CaptureOptions(refine=3, refine_seconds=SLOW / 2, relit="none")
    entry = capture_one(_Slow(), path, tmp_path / "b", short)
    assert handed[-1] == 0 and entry["refine"]["steps"] == 0  # the network took it all: no step
    record = json.loads((tmp_path / "b" / "material.json").read_text())["refine"]
    assert record["seconds_budget"] == SLOW / 2 and record["steps"] == 0


def test_shots_and_calibrated_captures_count_their_seconds_from_their_start(monkeypatch):
    from types import SimpleNamespace

    from svbrdf_models.capture import multiview

    views, real = [], multiview.refine_views

    def spy(*args, **kwargs):
        views.append(kwargs["seconds"])
        return real(*args, **kwargs)

    monkeypatch.setattr(multiview, "refine_views", spy)
    options = SimpleNamespace(refine=2, refine_seconds=10.0, backend="eager", metal="auto")
    photos, network = _photo(32), example_material("tiles", 32)
    multiview.refine_network(network, photos, [Scene.flash(intensity=12.0)], options, None, "cpu")
    assert views[-1] == 10.0  # no start given: the steps' own budget, as before
    began = time.monotonic() - SLOW  # the capture began a second ago (its network, its exposures)
    multiview.refine_network(network, photos, [Scene.flash(intensity=12.0)], options, None, "cpu", began=began)
    assert 0 < views[-1] <= 10.0 - SLOW - 32 * 32 * refining.AFTER_REFINE_SECONDS_PER_PIXEL
    late = time.monotonic() - 20.0  # the budget already spent: no step
    result = multiview.refine_network(network, photos, [Scene.flash(intensity=12.0)], options, None, "cpu",
                                      began=late)  # fmt: skip
    assert views[-1] == 0 and result.steps == 0
