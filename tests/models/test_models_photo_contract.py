"""``TrainedModel.predict``'s photo contract: linear floats in [0, 1], read by the public
``svbrdf_models.load_photo``; a photo still in 0-255, negative or empty is refused in one line
(issue 36: a 0-255 float photo used to give diffuse 0.44-0.98 without a word)."""

from __future__ import annotations

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models.errors import DataError
from svbrdf_render import Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb


@pytest.fixture(scope="module")
def model():
    return sm.load_model("pretrained")


@pytest.mark.parametrize(
    ("photo", "needle"),
    [
        (torch.rand(3, 64, 64) * 255, "needs svbrdf_render.srgb_to_linear(photo / 255)"),
        (torch.rand(3, 64, 64) - 0.5, "not linear values in [0, 1]"),
        (torch.zeros(3, 0, 64), "empty"),
    ],
)
def test_photos_outside_the_contract_are_refused(model, photo, needle):
    with pytest.raises(DataError) as e:
        model.predict(photo)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_load_photo_is_public_and_gives_what_predict_takes(model, tmp_path):
    linear = render(example_material("tiles", 80), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    path = write_image(tmp_path / "shot.png", linear_to_srgb(linear))
    photo, notes = sm.load_photo(path)
    assert photo.dtype == torch.float32 and photo.shape == (3, 80, 80)
    assert float(photo.min()) >= 0 and float(photo.max()) <= 1
    assert torch.allclose(photo, linear, atol=0.01)  # decoded back to linear
    maps = model.predict(photo)
    assert maps.size == (model.resolution, model.resolution)


def test_the_api_takes_a_numpy_integer_budget_and_refuses_what_memory_cannot_hold(model, monkeypatch):
    import numpy as np

    from svbrdf_render.plumbing import machine

    photo = torch.rand(3, 32, 32) * 0.5
    maps = model.predict(photo, refine=np.int64(1), backend="eager")
    assert maps.size == (32, 32)
    monkeypatch.setattr(machine, "available_memory", lambda: 2**20)
    with pytest.raises(DataError, match="needs about .* GB.*resize the photo smaller"):
        model.predict(photo, refine=1)


@pytest.mark.parametrize("refine", [0, 1])
def test_a_one_pixel_photo_is_refused(model, refine):
    with pytest.raises(DataError, match="too few pixels"):
        model.predict(torch.rand(3, 1, 1) * 0.5, refine=refine)
