"""The effect registry, and :func:`apply_image_effects`, the renderer's image phase on its own.

The registry declares each effect once (name, phase, parameters, range check, stage); the
renderer builds its plan from the declared phases. :func:`apply_image_effects` runs the image
phase of a declaration on radiance already rendered, by the renderer's own stages.
"""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import (
    DES18_EFFECTS,
    EFFECTS,
    PHOTO_EFFECTS,
    Scene,
    SceneError,
    apply_image_effects,
    build_plan,
    render,
)
from svbrdf_render.effects import PHASES


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_effect_declares_a_phase_and_a_stage_or_what_it_belongs_to(name):
    spec = EFFECTS[name]
    assert spec.name == name and spec.phase in PHASES and spec.doc
    if spec.stage is None:  # a parameter of the effect it requires (fresnel, masking)
        assert spec.requires and all(EFFECTS[r].stage is not None for r in spec.requires)
    for key, choices in spec.choices.items():
        assert spec.defaults[key] in choices


def test_the_plan_runs_the_phases_in_order_whatever_the_declaration_order():
    declared = ["gamma", "exposure", "falloff", "cosine", "masking", "fresnel", "specular", "diffuse"]
    plan = build_plan(Scene.flash(effects=declared).effects)
    order = [PHASES.index(EFFECTS[name].phase) for name in plan.stages]
    assert order == sorted(order) and plan.stages[:4] == ("diffuse", "specular", "fresnel", "masking")
    assert plan.stages[-2:] == ("exposure", "gamma")


def test_des18_is_the_shading_and_light_phases_of_the_photo_set():
    shading = {n for n in PHOTO_EFFECTS if EFFECTS[n].phase in ("shading", "light")}
    assert shading == set(DES18_EFFECTS)


# -- apply_image_effects ----------------------------------------------------------------------------

PHOTO = [*DES18_EFFECTS, {"exposure": {"ev": 1.5}}, {"noise": {"sigma": 0.02, "shot": 0.01, "seed": 3}},
         {"clip": {"max": 0.8}}, {"gamma": {"gamma": 2.4}}]


def test_apply_image_effects_is_what_render_does_after_shading():
    m = random_svbrdf(2, 16)
    scene = Scene.flash(intensity=3.0, effects=PHOTO)
    linear = render(m, scene.with_effects(DES18_EFFECTS))
    assert torch.equal(apply_image_effects(linear, scene.effects), render(m, scene))
    gen = lambda: torch.Generator().manual_seed(11)  # noqa: E731
    assert torch.equal(
        apply_image_effects(linear, scene.effects, generator=gen()), render(m, scene, generator=gen())
    )


def test_apply_image_effects_takes_any_declaration_and_skips_shading():
    x = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0))
    assert torch.equal(apply_image_effects(x, ["exposure"]), x * 1.0)
    assert torch.equal(apply_image_effects(x, {"exposure": {"ev": 1}}), x * 2)
    assert torch.equal(apply_image_effects(x, [*DES18_EFFECTS, {"exposure": {"ev": 1}}]), x * 2)
    assert torch.equal(apply_image_effects(x, DES18_EFFECTS), x)
    assert torch.equal(apply_image_effects(x, {"gamma": {"gamma": 2.0}}), x.clamp_min(1e-8).sqrt())


def test_apply_image_effects_passes_gradients_back():
    x = torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(1)).requires_grad_(True)
    apply_image_effects(x, {"exposure": {"ev": 2}}).sum().backward()
    assert torch.equal(x.grad, torch.full_like(x, 4.0))


@pytest.mark.parametrize(
    ("effects", "message"),
    [
        (["vignetting"], "effect 'vignetting' reads the camera; render the scene with render() instead"),
        (["exposur"], "unknown effect 'exposur'; did you mean 'exposure'?"),
        ({"clip": {"max": 0}}, "effect 'clip': max must be > 0, got 0"),
    ],
)
def test_apply_image_effects_rejects_what_it_cannot_run(effects, message):
    with pytest.raises(SceneError) as info:
        apply_image_effects(torch.ones(1, 3, 4, 4), effects)
    assert message in str(info.value)
