"""The benchmark's test set: fixed procedural images by default, Des18 folders and shards when given,\nbrought to the models' resolution by resizing (the field of view they trained at)."""

from __future__ import annotations

import math

import pytest
import torch

from svbrdf_bench.errors import BenchError
from svbrdf_bench.presets import TEST_SEED
from svbrdf_bench.testset import test_set as make_test_set
from svbrdf_train.data import ProceduralMaterials


def test_default_is_fixed_and_apart_from_training_data():
    a, b = make_test_set(None, 32, 3), make_test_set(None, 32, 3)
    assert len(a) == 3 and a[0]["input"].shape == (3, 32, 32)
    assert torch.equal(a[2]["maps"], b[2]["maps"])  # every model sees the same images
    train = ProceduralMaterials(3, 32, seed=0)
    assert not torch.equal(a[0]["maps"], train[0]["maps"])
    assert str(TEST_SEED) in a.description


def test_shards_are_resized_to_the_model_resolution(tmp_path):
    from svbrdf_train.data.fov import resize_sample
    from svbrdf_train.data.shards import ShardWriter

    data = ProceduralMaterials(2, 48, seed=3)
    with ShardWriter(tmp_path / "t.h5", 48, bits=16) as w:
        w.extend(data.batch([0, 1]))
    test = make_test_set(tmp_path / "t.h5", 32, 99)
    assert len(test) == 2  # the shard's samples, not the procedural count
    stored = test.data[1]
    expected = resize_sample(stored, 32)
    assert test[1]["input"].shape == (3, 32, 32) and test[1]["maps"].shape == (10, 32, 32)
    assert torch.equal(test[1]["maps"], expected["maps"]) and torch.equal(test[1]["input"], expected["input"])
    # The whole surface, not its centre: the mean albedo is kept, which a centre crop would not do.
    torch.testing.assert_close(test[1]["maps"][3:6].mean(), stored["maps"][3:6].mean(), atol=1e-3, rtol=0)
    same = make_test_set(tmp_path / "t.h5", 48, 99)  # at the shard's own size: as stored
    assert torch.equal(same[0]["maps"], test.data[0]["maps"])
    with pytest.raises(BenchError, match="smaller than the 64 px"):
        make_test_set(tmp_path / "t.h5", 64, 1)[0]


@pytest.mark.data
def test_des18_folder(shared_data):
    test = make_test_set(shared_data / "des18-dev", 256, 5)
    assert len(test) > 5 and test[0]["maps"].shape == (10, 256, 256)
    assert "Des18" in test.description and "resized to 256 px" in test.description
    # The whole 288 px tile at 256 px: its mean photo is the tile's, not the brighter centre's.
    tile = test.data[0]["input"]
    torch.testing.assert_close(test[0]["input"].mean(), tile.mean(), atol=2e-3, rtol=0)


def _smooth_material(size: int):
    """A material that varies slowly over [-1, 1]^2 (bumps, albedo gradients, a specular sheen), so
    that the area filter loses almost nothing of what the flash shows."""
    from svbrdf_render import SVBRDF, surface_positions

    x, y, _ = surface_positions(size, size)
    n = torch.stack([0.25 * torch.sin(math.pi * x), 0.25 * torch.cos(1.5 * math.pi * y), torch.ones_like(x)])
    n = n / n.norm(dim=0, keepdim=True)
    d = torch.stack([0.45 + 0.25 * torch.sin(2 * x), 0.35 + 0.2 * y, 0.25 + 0.1 * x * y])
    r = (0.45 + 0.2 * x)[None]
    s = (0.15 + 0.1 * y)[None].expand(3, -1, -1)
    return SVBRDF(n[None], d[None], r[None], s[None].contiguous())


def test_resized_samples_rerender_under_the_flash_of_the_full_photo():
    """The benchmark's way (resizing) keeps a sample consistent with its photo; a centre crop does not.

    A material is photographed at 96 px under a known flash; the flash is fitted to that full-size
    photo; the sample is brought to 32 px as the test set does. Its maps, re-rendered under the
    fitted flash (an image always covers [-1, 1]^2), match its resized photo; the centre 32 px of
    the same sample show a third of the surface's width, and re-rendered the same way they do not.
    """
    from svbrdf_bench.testset import TestSet
    from svbrdf_render import SVBRDF, Scene, fit_flash, render

    maps = _smooth_material(96)
    photo = render(maps, Scene.flash(2.0, intensity=9.0)).clamp(0, 1)
    fit = fit_flash(maps, photo, camera_distance=2.2, steps=300)  # starts from the Des18 distance
    assert float(fit.rmse[0]) < 1e-3  # the fit finds the flash the photo was taken under
    torch.testing.assert_close(fit.position[0], torch.tensor([0.0, 0.0, 2.0]), atol=0.02, rtol=0)

    sample = {"input": photo[0], "maps": maps.pack()[0], "name": "known"}
    small = TestSet([sample], 32, "one known material")[0]
    assert small["input"].shape == (3, 32, 32) and small["maps"].shape == (10, 32, 32)
    small_maps = SVBRDF.unpack(small["maps"][None], validate=False)
    rerender = render(small_maps, fit.scene(0)).clamp(0, 1)
    resized_rmse = float((rerender - small["input"][None]).square().mean().sqrt())

    crop_maps, crop_photo = maps.center_crop(32), photo[..., 32:64, 32:64]
    cropped = render(crop_maps, fit.scene(0)).clamp(0, 1)
    crop_rmse = float((cropped - crop_photo).square().mean().sqrt())

    spread = float(small["input"].std())  # how much the photo itself varies (about 0.13)
    assert resized_rmse < 0.005 and resized_rmse < 0.05 * spread, (resized_rmse, spread)
    assert crop_rmse > 0.5 * spread and crop_rmse > 20 * resized_rmse, (crop_rmse, resized_rmse)


def test_missing_and_wrong_paths_are_refused(tmp_path):
    with pytest.raises(BenchError, match="no such file"):
        make_test_set(tmp_path / "nowhere", 32, 1)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(BenchError, match="not a Des18 folder"):
        make_test_set(tmp_path / "notes.txt", 32, 1)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BenchError, match="no Des18 strips"):
        make_test_set(tmp_path / "empty", 32, 1)


def test_a_folder_of_photos_without_maps_is_refused_before_any_training(tmp_path):
    """Photos (one tile, no ground truth) are the wrong kind of folder: refused when the test set is
    made, which the benchmark does before it trains anything."""
    from svbrdf_render import write_image

    folder = tmp_path / "photos"
    folder.mkdir()
    write_image(folder / "photo.png", torch.rand(3, 48, 48))
    with pytest.raises(BenchError, match="cannot be read as materials with ground truth") as e:
        make_test_set(folder, 32, 1)
    assert str(folder) in str(e.value) and "photo.png" in str(e.value)
