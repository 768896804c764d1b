"""The ``beam`` effect: a flash's soft beam, ``cos^exponent`` of the angle off the light's axis.

The example of adding an effect: its declaration (name, phase, parameter, range check and stage)
is one ``_register`` call in ``svbrdf_render/effects.py``; these are its tests. The generic ones in
``test_effects.py`` (an undeclared effect runs no op; declaring one adds ops) cover it too, since
they run over every registered effect.
"""

from __future__ import annotations

import math

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import (
    DES18_EFFECTS,
    PHOTO_EFFECTS,
    SVBRDF,
    Camera,
    PointLight,
    Scene,
    SceneError,
    render,
    surface_positions,
)
from svbrdf_render.fused import supports

SIZE = 33


def _flat() -> SVBRDF:
    return SVBRDF.constant(1, SIZE, roughness=1.0)


def _scene(light_pos, effects, directional=False) -> Scene:
    light = PointLight(torch.as_tensor(light_pos, dtype=torch.float32), 2.0, directional=directional)
    return Scene(Camera(torch.tensor([0.0, 0.0, 2.0])), (light,), effects)


def _beam(exponent: float) -> list:
    return [*DES18_EFFECTS, {"beam": {"exponent": exponent}}]


@pytest.mark.parametrize("exponent", [1.0, 2.0, 7.5])
@pytest.mark.parametrize("light_pos", [(0.0, 0.0, 1.2), (0.4, -0.3, 1.5)])
def test_beam_scales_by_the_cosine_off_the_light_axis_to_the_power(light_pos, exponent):
    m = _flat()
    plain = render(m, _scene(light_pos, DES18_EFFECTS))
    beamed = render(m, _scene(light_pos, _beam(exponent)))
    # The axis runs from the light to the patch centre; the ray from the light to each pixel.
    pos = torch.tensor(light_pos, dtype=torch.float64).view(3, 1, 1)
    to_pixel = surface_positions(SIZE, SIZE, dtype=torch.float64) - pos
    cos = (to_pixel * -pos).sum(0) / (to_pixel.norm(dim=0) * pos.norm())
    expected = (cos**exponent).float()
    ratio = beamed[0] / plain[0]
    assert torch.allclose(ratio, expected.expand_as(ratio), rtol=1e-5)
    if light_pos[:2] == (0.0, 0.0):  # on the axis the centre pixel keeps all its light
        assert float(ratio[:, SIZE // 2, SIZE // 2].min()) == pytest.approx(1.0, abs=1e-6)
        corner = 1.2 / math.sqrt(1.2**2 + 2 * (32 / 33) ** 2)
        assert float(ratio[0, 0, 0]) == pytest.approx(corner**exponent, rel=1e-4)


def test_beam_leaves_directional_lights_alone():
    m = random_svbrdf(1, 16)
    sun = (0.5, 0.2, 0.8)
    assert torch.equal(render(m, _scene(sun, _beam(3.0), True)), render(m, _scene(sun, DES18_EFFECTS, True)))
    # A per-configuration mix: the directional configuration is untouched, the point one dims.
    lights = torch.tensor([[0.5, 0.2, 0.8], [0.5, 0.2, 0.8]])
    mixed = PointLight(lights, 2.0, directional=torch.tensor([True, False]))
    cam = Camera(torch.tensor([0.0, 0.0, 2.0]))
    plain = render(m, Scene(cam, (mixed,), DES18_EFFECTS))
    beamed = render(m, Scene(cam, (mixed,), _beam(3.0)))
    assert torch.equal(beamed[:, 0], plain[:, 0])
    assert float((beamed[:, 1] - plain[:, 1]).max()) <= 0 and float((plain[:, 1] - beamed[:, 1]).max()) > 0


def test_exponent_zero_gives_the_image_without_the_beam():
    m = random_svbrdf(1, 16)
    pos = (0.3, 0.1, 1.4)
    assert torch.allclose(render(m, _scene(pos, _beam(0.0))), render(m, _scene(pos, DES18_EFFECTS)))


def test_beam_is_off_by_default():
    default = Scene(Camera(), (PointLight(torch.tensor([0.0, 0.0, 2.0]), 1.0),))
    assert "beam" not in Scene.flash().effects and "beam" not in default.effects
    assert "beam" not in DES18_EFFECTS and "beam" not in PHOTO_EFFECTS
    assert Scene.flash(effects=["beam"]).effects["beam"] == {"exponent": 2.0}


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"exponent": -1.0}, "exponent must be in [0, 1000], got -1.0"),
        ({"exponent": 1e4}, "exponent must be in [0, 1000]"),
        ({"exponent": "wide"}, "exponent must be a number"),
        ({"exponent": True}, "exponent must be a number"),
        ({"expo": 2.0}, "did you mean 'exponent'"),
        ({"power": 2.0}, "'power' Known: exponent"),
    ],
)
def test_beam_parameters_are_range_checked(params, message):
    with pytest.raises(SceneError, match="effect 'beam'") as info:
        Scene.flash(effects=[*DES18_EFFECTS, {"beam": params}])
    assert message in str(info.value)


# -- hard cases, forward and backward ---------------------------------------------------------------

HARD_LIGHTS = {
    "grazing": (6.0, 0.0, 0.05),  # far to the side and low: rays almost perpendicular to the axis
    "near the surface": (0.9, 0.9, 1e-3),
    "on axis, close": (0.0, 0.0, 0.05),
}


@pytest.mark.parametrize("exponent", [0.0, 0.5, 2.0, 1000.0])
@pytest.mark.parametrize("light", list(HARD_LIGHTS))
def test_hard_cases_are_finite_and_bounded_forward_and_backward(light, exponent):
    m = random_svbrdf(2, 12)
    maps = [t.detach().clone().requires_grad_(True) for t in m.maps().values()]
    pos = torch.tensor(HARD_LIGHTS[light], requires_grad=True)
    scene = Scene(Camera(torch.tensor([0.0, 0.0, 2.0])), (PointLight(pos, 1.0),), _beam(exponent))
    out = render(SVBRDF(*maps, validate=False), scene)
    plain = render(m, scene.with_effects(DES18_EFFECTS))
    assert torch.isfinite(out).all()
    out_value = out.detach()
    assert float(out_value.min()) >= 0 and bool((out_value <= plain * (1 + 1e-5) + 1e-12).all())  # factor in [0, 1]
    out.sum().backward()
    for t in (*maps, pos):
        assert t.grad is not None and torch.isfinite(t.grad).all()
        assert float(t.grad.abs().max()) <= 1e12


def test_beam_gradients_match_finite_differences():
    m = random_svbrdf(1, 4)
    maps = SVBRDF(*(t.double() for t in m.maps().values()), validate=False)

    def image(pos, roughness):
        lit = SVBRDF(maps.normal, maps.diffuse, roughness, maps.specular, validate=False)
        scene = Scene(Camera(torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)), (PointLight(pos, 1.0),),
                      _beam(3.0))
        return render(lit, scene)

    pos = torch.tensor([0.3, -0.2, 1.1], dtype=torch.float64, requires_grad=True)
    rough = maps.roughness.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(image, (pos, rough))


def test_the_hand_derived_backward_is_not_used_with_the_beam():
    # svbrdf_render.fused differentiates the Des18 shading only; a beam changes that shading,
    # while image effects (which run after it) do not.
    assert supports(Scene.flash(effects=DES18_EFFECTS).effects)
    assert supports(Scene.flash(effects=[*DES18_EFFECTS, "exposure", "gamma"]).effects)
    assert not supports(Scene.flash(effects=_beam(2.0)).effects)
