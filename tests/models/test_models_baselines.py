"""The baselines ``mean`` and ``photo``: what each computes, and that it needs no training.

The zoo tests (test_models_zoo.py) run them like every other generator; these check the
documented rule of each one on photos whose answer is known.
"""

from __future__ import annotations

import math

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models.networks.baselines import (
    MEAN_DIFFUSE_SCALE,
    PHOTO_DIFFUSE_SCALE,
    ROUGHNESS,
    SPECULAR,
    flash_falloff,
)
from svbrdf_render import DES18_DISTANCE, SVBRDF, Scene, render

BASELINES = ("mean", "photo")


@pytest.mark.parametrize("name", BASELINES)
def test_baselines_are_registered_generators_without_parameters(name):
    assert name in sm.list_models("generator")
    info = sm.describe("generator", name)
    assert info.distribution == "svbrdf-models" and "baseline" in info.description
    assert all(f.doc for f in info.fields)
    g = sm.create_generator(name)
    assert isinstance(g, torch.nn.Module)
    assert list(g.parameters()) == [] and list(g.buffers()) == [] and g.state_dict() == {}


def test_mean_of_a_uniform_photo_is_the_documented_constants():
    value = torch.tensor([0.1, 0.2, 0.3])
    photo = value.view(1, 3, 1, 1).expand(2, 3, 16, 24).clone()
    maps = sm.create_generator("mean")(photo)
    assert maps.shape == (2, 16, 24)
    torch.testing.assert_close(
        maps.diffuse, (MEAN_DIFFUSE_SCALE * value).view(1, 3, 1, 1).expand(2, 3, 16, 24)
    )
    torch.testing.assert_close(
        maps.normal, torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(2, 3, 16, 24)
    )
    assert torch.all(maps.roughness == ROUGHNESS) and torch.all(maps.specular == SPECULAR)
    # Configured constants are used as given.
    maps = sm.create_generator("mean", {"diffuse_scale": 2.0, "roughness": 0.8, "specular": 0.5})(photo)
    torch.testing.assert_close(maps.diffuse[0, :, 5, 7], 2.0 * value)
    assert torch.all(maps.roughness == 0.8) and torch.all(maps.specular == 0.5)


def test_mean_diffuse_ignores_the_highlight():
    # A bright highlight on 30% of the pixels does not move the median.
    photo = torch.full((1, 3, 20, 20), 0.2)
    photo[:, :, 6:14, 4:19] = 1.0
    g = sm.create_generator("mean", {"diffuse_scale": 1.0})
    torch.testing.assert_close(g(photo).diffuse, torch.full((1, 3, 20, 20), 0.2))
    # A scale that would pass 1 is clamped.
    assert torch.all(sm.create_generator("mean", {"diffuse_scale": 10.0})(photo).diffuse == 1.0)


def test_flash_falloff_is_d_over_r_cubed():
    f = flash_falloff(4, 4, 2.0)
    # Pixel centres of a 4-px image of [-1, 1]: +-0.25 and +-0.75.
    for (row, col), (x, y) in {(0, 0): (-0.75, 0.75), (1, 2): (0.25, 0.25), (3, 1): (-0.25, -0.75)}.items():
        r = math.sqrt(x * x + y * y + 4.0)
        assert float(f[0, 0, row, col]) == pytest.approx((2.0 / r) ** 3, rel=1e-6)
    assert float(flash_falloff(5, 5, 2.0)[0, 0, 2, 2]) == pytest.approx(1.0)


@pytest.mark.parametrize("size", [(64, 64), (32, 48)])
def test_photo_recovers_a_uniform_albedo_under_the_des18_flash(size):
    """A Lambertian material (no specular) photographed under the Des18 flash: the photo baseline
    divides the flash's fall-off out and gives back one albedo everywhere."""
    albedo = torch.tensor([0.6, 0.4, 0.2])
    material = SVBRDF.constant(1, size, diffuse=albedo.tolist(), roughness=0.8, specular=(0.0, 0.0, 0.0))
    intensity = 12.0
    photo = render(material, Scene.flash(DES18_DISTANCE, intensity))
    assert float(photo[0, 0].max() / photo[0, 0].min()) > 1.3  # the fall-off is visible in the photo
    maps = sm.create_generator("photo")(photo)
    d = maps.diffuse[0]
    spread = (d.amax(dim=(1, 2)) - d.amin(dim=(1, 2))) / d.mean(dim=(1, 2))
    assert float(spread.max()) < 0.01  # nearly uniform
    # The albedo itself, up to the documented constant: photo = albedo x I / (pi d^2) at the centre.
    scale = math.pi * DES18_DISTANCE**2 / intensity
    exact = sm.create_generator("photo", {"diffuse_scale": scale})(photo).diffuse[0]
    torch.testing.assert_close(exact.mean(dim=(1, 2)), albedo, rtol=0.01, atol=0)
    torch.testing.assert_close(d.mean(dim=(1, 2)), albedo * PHOTO_DIFFUSE_SCALE / scale, rtol=0.01, atol=0)
    assert torch.all(maps.specular == 0) and torch.all(maps.roughness == ROUGHNESS)
    assert torch.all(maps.normal[:, 2] == 1)


def test_photo_clamps_to_the_unit_range():
    photo = torch.rand(1, 3, 16, 16) * 5 - 1
    d = sm.create_generator("photo", {"diffuse_scale": 1.0})(photo).diffuse
    assert d.min() == 0 and d.max() == 1


@pytest.mark.parametrize(
    ("name", "config", "needle"),
    [
        ("mean", {"roughness": 1.5}, "roughness"),
        ("mean", {"specular": -0.1}, "specular"),
        ("mean", {"diffuse_scale": -1.0}, "diffuse_scale"),
        ("photo", {"distance": 0.0}, "distance"),
        ("photo", {"specular": 0.1}, "specular"),  # photo has no specular field: it is 0 by definition
    ],
)
def test_bad_configs_are_refused(name, config, needle):
    with pytest.raises(sm.ConfigError, match=needle):
        sm.create_generator(name, config)


@pytest.mark.data
def test_defaults_minimise_each_map_rmse_on_des18_dev(shared_data):
    """The defaults are the per-map RMSE optima on des18-dev at 128 px (the benchmark's test set):
    moving any constant by 10% either way scores no better."""
    from svbrdf_bench.testset import test_set

    test = test_set(shared_data / "des18-dev", 128, 0)
    items = [test[i] for i in range(len(test))]
    photos = torch.stack([s["input"] for s in items])
    truth = SVBRDF.unpack(torch.stack([s["maps"] for s in items]), validate=False)

    def rmse(name: str, field: str, value: float, map_name: str) -> float:
        pred = sm.create_generator(name, {field: value})(photos)
        t, p = getattr(truth, map_name), getattr(pred, map_name)
        return float((p - t).square().flatten(1).mean(1).sqrt().mean())

    for name, field, value, map_name in (
        ("mean", "diffuse_scale", MEAN_DIFFUSE_SCALE, "diffuse"),
        ("photo", "diffuse_scale", PHOTO_DIFFUSE_SCALE, "diffuse"),
        ("mean", "roughness", ROUGHNESS, "roughness"),
        ("mean", "specular", SPECULAR, "specular"),
    ):
        best = rmse(name, field, value, map_name)
        for factor in (0.9, 1.1):
            assert rmse(name, field, value * factor, map_name) > best, (name, field, factor)
