"""Effects: each one does what it says, and an undeclared effect costs nothing.

"Costs nothing" is checked by counting the aten ops a render runs (forward and
backward): a scene without an effect runs exactly the ops of a renderer that never heard
of the effect, while declaring the same effect with neutral parameters adds ops.
"""

from __future__ import annotations

import math

import pytest
import torch

import svbrdf_render.effects as effects_module
import svbrdf_render.renderer as render_module
from conftest import random_svbrdf
from svbrdf_render import (
    DES18_EFFECTS,
    EFFECTS,
    SVBRDF,
    Camera,
    PointLight,
    Scene,
    build_plan,
    render,
)

ALL = list(EFFECTS)
IMAGE_EFFECTS = ["vignetting", "exposure", "noise", "clip", "tone", "gamma"]
NEUTRAL = {
    "vignetting": {"strength": 0.0},
    "exposure": {"ev": 0.0},
    "noise": {"sigma": 0.0},
    "clip": {"max": 1e30},
    "tone": {"power": 1.0, "shoulder": 0.0},
    "gamma": {"gamma": 1.0},
}


def _scene(effects) -> Scene:
    return Scene(
        Camera(torch.tensor([[0.1, 0.0, 2.0], [0.0, 0.3, 1.5]])),
        (PointLight(torch.tensor([[0.5, 0.2, 1.5], [-0.3, 0.1, 2.5]]), 6.0),),
        effects,
    )


def _without(name: str) -> list[str]:
    drop = {name}
    if name == "specular":  # fresnel and masking modify the specular lobe
        drop |= {"fresnel", "masking"}
    return [e for e in ALL if e not in drop]


def _count(counter_cls, m: SVBRDF, scene: Scene, backward: bool):
    m = SVBRDF(*(t.detach().requires_grad_(backward) for t in m.maps().values()))
    counter = counter_cls()
    with counter:
        out = render(m, scene)
        if backward:
            out.sum().backward()
    return counter.counts


@pytest.mark.parametrize("backward", [False, True], ids=["forward", "forward+backward"])
@pytest.mark.parametrize("name", ALL)
def test_an_undeclared_effect_runs_no_op(name, backward, op_counter, monkeypatch):
    m = random_svbrdf(1, 8)
    scene = _scene(_without(name))
    known = _count(op_counter, m, scene, backward)

    # A renderer that never heard of the effect: drop it from the registry, forget every
    # plan built so far, and render the same scene again.
    monkeypatch.delitem(effects_module.EFFECTS, name)
    monkeypatch.setattr(render_module, "_PLANS", {})
    never_heard = _count(op_counter, m, _scene(_without(name)), backward)
    assert known == never_heard
    assert name not in build_plan(scene.effects).stages


@pytest.mark.parametrize("name", ALL)
def test_declaring_an_effect_adds_ops(name, op_counter):
    m = random_svbrdf(1, 8)
    without = _count(op_counter, m, _scene(_without(name)), False)
    with_it = _count(op_counter, m, _scene(ALL), False)
    assert sum(with_it.values()) > sum(without.values())


@pytest.mark.parametrize("name", IMAGE_EFFECTS)
def test_neutral_parameters_cost_ops_that_absence_does_not(name, op_counter):
    # Multiplying by one is not absence: a neutral declaration gives the same image but
    # runs more ops than leaving the effect out.
    m = random_svbrdf(1, 8)
    base = list(DES18_EFFECTS)
    neutral = {**{e: {} for e in base}, name: NEUTRAL[name]}
    absent_ops = _count(op_counter, m, _scene(base), False)
    neutral_ops = _count(op_counter, m, _scene(neutral), False)
    assert sum(neutral_ops.values()) > sum(absent_ops.values())
    assert torch.allclose(render(m, _scene(neutral)), render(m, _scene(base)), atol=1e-7)


# -- what each effect does ------------------------------------------------------------------


def _flat(size=9, **kw) -> SVBRDF:
    return SVBRDF.constant(1, size, **kw)


def _center(img: torch.Tensor) -> torch.Tensor:
    return img[0, :, img.shape[-2] // 2, img.shape[-1] // 2]


def test_diffuse_and_specular_match_the_formulas_at_the_centre():
    # Odd size: one pixel centre sits at the origin, where n = l = v = h = +z.
    d, s, r, dist, power = 0.6, 0.04, 0.5, 2.0, 7.0
    m = _flat(diffuse=(d, d, d), specular=(s, s, s), roughness=r)
    cam = Camera(torch.tensor([0.0, 0.0, dist]))
    light = (PointLight(torch.tensor([0.0, 0.0, dist]), power),)
    lit = power / dist**2
    diffuse = _center(render(m, Scene(cam, light, ["diffuse", "cosine", "falloff"])))
    assert torch.allclose(diffuse, torch.full((3,), d * (1 - s) / math.pi * lit), rtol=1e-6)
    alpha = 1e-3 + (1 - 1e-3) * r * r
    D = 1 / (math.pi * alpha**2)
    F = s + (1 - s) * 2 ** (-5.55473 - 6.98316)
    spec = _center(render(m, Scene(cam, light, ["specular", "fresnel", "masking", "cosine", "falloff"])))
    assert torch.allclose(spec, torch.full((3,), D * F / 4 * lit), rtol=1e-5)  # V = 1 here
    no_fresnel = _center(render(m, Scene(cam, light, ["specular", "cosine", "falloff"])))
    assert torch.allclose(no_fresnel, torch.full((3,), D * s / 4 * lit), rtol=1e-5)


def test_cosine_and_falloff():
    m = _flat(roughness=1.0)
    cam = Camera(torch.tensor([0.0, 0.0, 2.0]))
    theta = math.radians(60)
    sun = PointLight(torch.tensor([math.sin(theta), 0.0, math.cos(theta)]), 1.0, directional=True)
    with_cos = render(m, Scene(cam, (sun,), ["diffuse", "cosine"]))
    without = render(m, Scene(cam, (sun,), ["diffuse"]))
    assert torch.allclose(with_cos, without * math.cos(theta), rtol=1e-5)
    near = render(m, Scene(cam, (PointLight(torch.tensor([0.0, 0.0, 50.0]), 1.0),), ["diffuse", "falloff"]))
    far = render(m, Scene(cam, (PointLight(torch.tensor([0.0, 0.0, 100.0]), 1.0),), ["diffuse", "falloff"]))
    assert torch.allclose(near / far, torch.full_like(near, 4.0), rtol=1e-3)


def test_image_effects():
    m = random_svbrdf(1, 16)
    base = list(DES18_EFFECTS)
    x = render(m, _scene(base))
    assert torch.allclose(render(m, _scene(base + [{"exposure": {"ev": 1.0}}])), 2 * x)
    clipped = render(m, _scene(base + [{"exposure": {"ev": 4.0}}, {"clip": {"max": 0.5}}]))
    assert float(clipped.max()) == pytest.approx(0.5) and float(clipped.min()) >= 0
    g = render(m, _scene(base + ["gamma"]))
    assert torch.allclose(g, x.clamp_min(1e-8) ** (1 / 2.2), rtol=1e-5)


def test_vignetting_darkens_the_corners_only():
    m = _flat(size=33)
    scene = Scene(Camera(torch.tensor([0.0, 0.0, 1.2])), (PointLight(torch.tensor([0.0, 0.0, 1.2]), 2.0),))
    plain = render(m, scene)
    vig = render(m, scene.with_effects(list(DES18_EFFECTS) + ["vignetting"]))
    ratio = vig / plain
    assert float(ratio[0, :, 16, 16].min()) == pytest.approx(1.0, abs=1e-6)
    corner_cos = 1.2 / math.sqrt(1.2**2 + 2 * (32 / 33) ** 2)
    assert float(ratio[0, 0, 0, 0]) == pytest.approx(corner_cos**4, rel=1e-4)


def test_noise_is_seeded_and_has_the_declared_spread():
    m = _flat(size=64)
    fx = list(DES18_EFFECTS)
    clean = render(m, Scene.flash(effects=fx))
    a = render(m, Scene.flash(effects=fx + [{"noise": {"sigma": 0.05, "seed": 1}}]))
    b = render(m, Scene.flash(effects=fx + [{"noise": {"sigma": 0.05, "seed": 1}}]))
    c = render(m, Scene.flash(effects=fx + [{"noise": {"sigma": 0.05, "seed": 2}}]))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert float((a - clean).std()) == pytest.approx(0.05, rel=0.05)
    gen = torch.Generator().manual_seed(7)
    d = render(m, Scene.flash(effects=fx + [{"noise": {"sigma": 0.05, "seed": 1}}]), generator=gen)
    assert not torch.equal(a, d)
    shot = render(m, Scene.flash(intensity=40.0, effects=fx + [{"noise": {"sigma": 0.0, "shot": 0.01}}]))
    bright = render(m, Scene.flash(intensity=40.0, effects=fx))
    expected = torch.sqrt(0.01 * bright).mean()
    assert float((shot - bright).std()) == pytest.approx(float(expected), rel=0.1)
