"""Light/view configurations: the training loss's and the evaluation protocol's."""

from __future__ import annotations

import torch

from conftest import random_svbrdf
from svbrdf_render import evaluation_scene, render, training_scene
from svbrdf_render.sampling import cosine_weighted_directions


def _g(seed):
    return torch.Generator().manual_seed(seed)


def test_cosine_weighted_directions_are_unit_upper_and_cosine_distributed():
    d = cosine_weighted_directions((20000,), _g(0), low=0.0, high=1.0)
    assert torch.allclose(d.norm(dim=-1), torch.ones(20000), atol=1e-6)
    assert float(d[:, 2].min()) >= 0
    # For a cosine-weighted hemisphere, E[cos] = 2/3 and E[cos^2] = 1/2.
    assert abs(float(d[:, 2].mean()) - 2 / 3) < 0.01
    assert abs(float((d[:, 2] ** 2).mean()) - 0.5) < 0.01


def test_training_scene_shapes_and_kinds():
    s = training_scene(4, generator=_g(0))
    assert s.config_shape == (4, 9)
    directional = s.camera.directional
    assert directional[:, :3].all() and not directional[:, 3:].any()
    assert torch.equal(s.lights[0].directional, directional)
    assert render(random_svbrdf(4, 8), s).shape == (4, 9, 3, 8, 8)


def test_training_scene_mirror_configurations_share_a_shift():
    s = training_scene(3, generator=_g(1))
    cam, light = s.camera.position[:, 3:], s.lights[0].position[:, 3:]
    # light = mirror(dir) * dl + shift, view = dir * dv + shift, shift at z ~ 1e-4:
    # both directions have the same elevation, opposite azimuth.
    v = cam - torch.cat([cam[..., :2] * 0, cam[..., 2:] * 0], -1)
    shift_free_v = v[..., :2] / v[..., 2:]  # tan(theta) (cos phi, sin phi) + shift/z
    shift_free_l = light[..., :2] / light[..., 2:]
    # With the same shift s: v_xy/v_z - s/v_z = -(l_xy/l_z - s/l_z); solve for s and check
    # it lies in the patch, proving the mirror construction.
    zv, zl = cam[..., 2:], light[..., 2:]
    shift = (shift_free_v + shift_free_l) / (1 / zv + 1 / zl)
    assert float(shift.abs().max()) <= 1.0 + 1e-4
    mirrored_v = (cam[..., :2] - shift) / zv
    mirrored_l = (light[..., :2] - shift) / zl
    assert torch.allclose(mirrored_v, -mirrored_l, atol=1e-4)


def test_training_scene_is_reproducible_per_seed():
    a, b, c = training_scene(2, generator=_g(5)), training_scene(2, generator=_g(5)), training_scene(2, generator=_g(6))
    assert torch.equal(a.camera.position, b.camera.position)
    assert torch.equal(a.lights[0].position, b.lights[0].position)
    assert not torch.equal(a.camera.position, c.camera.position)


def test_evaluation_scene_is_fixed_and_independent_of_the_global_rng():
    torch.manual_seed(123)
    a = evaluation_scene()
    torch.manual_seed(999)
    torch.rand(10)
    b = evaluation_scene()
    assert a.config_shape == (6,)
    assert torch.equal(a.camera.position, b.camera.position)
    assert torch.equal(a.lights[0].position, b.lights[0].position)
    assert not torch.equal(a.camera.position, evaluation_scene(seed=1).camera.position)
    # Every configuration sees and lights the patch from above, within 45 degrees.
    for pos in (a.camera.position, a.lights[0].position):
        cos = pos[:, 2] / pos.norm(dim=-1)
        assert float(cos.min()) >= 2**-0.5 - 1e-6
    m = random_svbrdf(3, 8)
    out = render(m, a)
    assert out.shape == (3, 6, 3, 8, 8) and float(out.mean()) > 0
