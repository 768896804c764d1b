"""The tone effect: a phone's tone curve left in a linearised photo (power, then shoulder)."""

from __future__ import annotations

import pytest
import torch

from svbrdf_render import DES18_EFFECTS, SVBRDF, Scene, SceneError, apply_image_effects, render


def _tone(x: torch.Tensor, **params) -> torch.Tensor:
    return apply_image_effects(x, {"tone": params})


def test_tone_is_the_power_then_the_shoulder():
    x = torch.linspace(0.01, 1.0, 50).view(1, 1, 1, 50).expand(1, 3, 1, 50)
    assert torch.allclose(_tone(x, power=1.3), x**1.3, rtol=1e-6)
    y = x**0.8
    assert torch.allclose(_tone(x, power=0.8, shoulder=2.0), y * 3 / (1 + 2 * y), rtol=1e-6)


@pytest.mark.parametrize("params", [{"power": 0.7}, {"power": 1.4}, {"shoulder": 3.0}, {"power": 0.8, "shoulder": 1.0}])
def test_tone_keeps_black_and_white_and_order(params):
    x = torch.linspace(0.0, 1.0, 101).view(1, 1, 1, 101)
    y = _tone(x, **params)
    assert float(y[..., 0]) == pytest.approx(0.0, abs=1e-4)
    assert float(y[..., -1]) == pytest.approx(1.0, abs=1e-6)
    assert bool((y[..., 1:] > y[..., :-1]).all())  # strictly increasing: no two levels merge


def test_a_shoulder_lifts_the_middle_and_compresses_the_top():
    x = torch.tensor([0.2, 0.9]).view(1, 1, 1, 2)
    y = _tone(x, shoulder=2.0)
    assert float(y[..., 0]) > 0.2 and float(y[..., 1]) > 0.9
    assert float(y[..., 1] - y[..., 0]) < 0.7  # the top of the range is compressed


@pytest.mark.parametrize("power,shoulder", [(0.25, 0.0), (4.0, 0.0), (0.25, 20.0), (1.0, 20.0)])
def test_tone_at_its_extremes_is_finite_forward_and_backward(power, shoulder):
    m = SVBRDF.constant(1, 8, diffuse=(0.0, 0.5, 1.0), roughness=0.05)
    x = torch.tensor([0.0, 1e-12, 1e-4, 0.5, 1.0, 3.0, 1e6]).view(1, 1, 1, 7).requires_grad_(True)
    y = _tone(x, power=power, shoulder=shoulder)
    y.sum().backward()
    assert torch.isfinite(y).all() and torch.isfinite(x.grad).all()
    assert float(y.detach().min()) >= 0
    scene = Scene.flash(effects=list(DES18_EFFECTS) + [{"tone": {"power": power, "shoulder": shoulder}}])
    maps = SVBRDF(*(t.detach().requires_grad_(True) for t in m.maps().values()))
    img = render(maps, scene)
    img.sum().backward()
    assert torch.isfinite(img).all()
    assert all(torch.isfinite(t.grad).all() for t in maps.maps().values())


@pytest.mark.parametrize("params", [{"power": 0.1}, {"power": 5.0}, {"shoulder": -0.5}, {"shoulder": 21.0}])
def test_tone_out_of_range_is_refused(params):
    with pytest.raises(SceneError, match="tone"):
        Scene.flash(effects=list(DES18_EFFECTS) + [{"tone": params}])
