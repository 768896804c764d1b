"""Numerical hard cases, forward and backward: finite, and bounded.

Bounds used below (radiance per unit light intensity at distance ~1):
- the GGX peak at the smallest alpha (1e-3) is 1/(pi alpha^2) ~ 3.2e5 and the Schlick-GGX
  visibility at grazing at most 1/k^2 = 4e6 (k = alpha/2); their product is never reached
  at once, so radiance stays below 1e7 per unit intensity;
- gradients are checked below 1e12 per unit intensity: several orders of magnitude below
  float32 overflow, and far below what an unguarded normalisation (1e12 per *unit* step at a
  zero normal) or a masked NaN branch would give (non-finite).
"""

from __future__ import annotations

import math

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import (
    DES18_EFFECTS,
    SVBRDF,
    Camera,
    PointLight,
    Scene,
    log_radiance,
    render,
)

MASKING = ["schlick-ggx", "smith", "height-correlated"]
RADIANCE_BOUND = 1e7
GRAD_BOUND = 1e12


def _effects(masking="schlick-ggx", fresnel="des18", extra=()):
    fx = {e: {} for e in DES18_EFFECTS}
    fx["masking"] = {"model": masking}
    fx["fresnel"] = {"model": fresnel}
    for e in extra:
        fx[e] = {}
    return fx


def _leaf(m: SVBRDF) -> SVBRDF:
    return SVBRDF(*(t.detach().clone().requires_grad_(True) for t in m.maps().values()), validate=False)


def _check(m: SVBRDF, scene: Scene, intensity: float = 1.0, loss=lambda x: x.sum()):
    """Render, back-propagate, and assert everything is finite and bounded."""
    m = _leaf(m)
    out = render(m, scene)
    assert torch.isfinite(out).all(), "non-finite radiance"
    assert float(out.detach().abs().max()) <= RADIANCE_BOUND * max(intensity, 1.0)
    loss(out).backward()
    for name, t in m.maps().items():
        assert t.grad is not None, f"no gradient reaches {name}"
        assert torch.isfinite(t.grad).all(), f"non-finite gradient for {name}"
        assert float(t.grad.abs().max()) <= GRAD_BOUND * max(intensity, 1.0), name
    return out, m


def _on_axis(dist=1.0, intensity=1.0, effects=None) -> Scene:
    p = torch.tensor([0.0, 0.0, dist])
    return Scene(Camera(p), (PointLight(p, intensity),), effects or _effects())


@pytest.mark.parametrize("masking", MASKING)
@pytest.mark.parametrize("roughness", [0.0, 1.0])
@pytest.mark.parametrize("floor", ["remap", "clamp"])
def test_roughness_zero_and_one(masking, roughness, floor):
    m = SVBRDF.constant(1, 9, roughness=roughness)
    fx = _effects(masking)
    fx["specular"] = {"alpha_floor": floor}
    out, leaf = _check(m, _on_axis(effects=fx))
    if roughness == 0.0:  # the mirror peak at the centre is the brightest pixel, and finite
        assert float(out.detach()[0, :, 4, 4].min()) > 1e3


def test_clamped_floor_has_no_roughness_gradient_below_it_and_remap_does():
    m = SVBRDF.constant(1, 9, roughness=0.02)  # below sqrt(1e-3) ~ 0.032
    grads = {}
    for floor in ("clamp", "remap"):
        fx = _effects()
        fx["specular"] = {"alpha_floor": floor}
        leaf = _leaf(m)
        log_radiance(render(leaf, _on_axis(effects=fx))).sum().backward()
        grads[floor] = leaf.roughness.grad.abs().max()
    assert float(grads["clamp"]) == 0.0
    assert float(grads["remap"]) > 0.0


@pytest.mark.parametrize("masking", MASKING)
@pytest.mark.parametrize(
    "light, camera",
    [
        ([5.0, 0.0, 0.0], [0.0, 0.0, 2.0]),  # light in the surface plane: n.l = 0
        ([0.0, 3.0, -1.0], [0.0, 0.0, 2.0]),  # light below the surface: n.l < 0
        ([0.0, 0.0, 2.0], [4.0, 0.0, 0.0]),  # camera at grazing: n.v = 0
        ([0.0, 0.0, 2.0], [0.0, 1.0, -2.0]),  # camera below: n.v < 0
        ([-5.0, 0.0, 0.0], [5.0, 0.0, 0.0]),  # both grazing, opposite: l + v ~ 0 at the centre
    ],
)
def test_grazing_and_back_facing_light_and_view(masking, light, camera):
    m = random_svbrdf(1, 9, tilt=0.0)  # flat normals so the cosines are exactly as set
    scene = Scene(Camera(torch.tensor(camera)), (PointLight(torch.tensor(light), 10.0),), _effects(masking))
    out, _ = _check(m, scene, 10.0)
    assert float(out.detach().abs().max()) <= 1e-5  # nothing lit from or seen at/behind the horizon


@pytest.mark.parametrize("masking", MASKING)
def test_normals_perpendicular_or_facing_away(masking):
    m = random_svbrdf(1, 6)
    n = m.normal.detach().clone()
    n[:, :, 0, :] = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1)  # n.v ~ 0
    n[:, :, 1, :] = torch.tensor([0.0, 0.0, -1.0]).view(1, 3, 1)  # facing into the surface
    m = SVBRDF(n, m.diffuse, m.roughness, m.specular)
    out, _ = _check(m, _on_axis(2.0, 5.0, _effects(masking)), 5.0)
    assert float(out.detach()[:, :, 1].abs().max()) == 0.0


@pytest.mark.parametrize("where", [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 1e-7]])
def test_light_on_the_surface(where):
    m = random_svbrdf(1, 9)  # odd size: a pixel centre sits exactly at the origin
    scene = Scene(Camera(torch.tensor([0.0, 0.0, 2.0])), (PointLight(torch.tensor(where), 1.0),), _effects())
    _check(m, scene)


def test_zero_nan_inf_and_non_unit_normals():
    m = random_svbrdf(1, 8, seed=4)
    n = m.normal.detach().clone()
    n[:, :, 2, 2] = 0.0
    n[:, 0, 3, 3] = float("nan")
    n[:, :, 4, 4] = float("inf")
    n[:, :, 5, 5] = 1e-30
    bad = [(2, 2), (3, 3), (4, 4), (5, 5)]
    n[:, :, 6, :] *= 5.0  # non-unit: same as unit
    scene = _on_axis(2.0, 5.0)
    out, leaf = _check(SVBRDF(n, m.diffuse, m.roughness, m.specular), scene, 5.0)
    flat_n = n.clone()
    for i, j in bad:
        flat_n[:, :, i, j] = torch.tensor([0.0, 0.0, 1.0])
    flat_n[:, :, 6, :] /= 5.0
    expected = render(SVBRDF(flat_n, m.diffuse, m.roughness, m.specular), scene)
    assert torch.allclose(out, expected, rtol=1e-5, atol=1e-7)  # fallback is (0, 0, 1)
    for i, j in bad:  # and gets no gradient
        assert float(leaf.normal.grad[:, :, i, j].abs().max()) == 0.0
    assert float(leaf.normal.grad[:, :, 0, 0].abs().max()) > 0.0


@pytest.mark.parametrize("intensity", [1e-3, 1.0, 1e3, 1e6])
def test_intensity_range(intensity):
    m = random_svbrdf(1, 8, roughness=(0.0, 1.0))
    out, _ = _check(m, _on_axis(1.5, intensity), intensity)
    unit = render(m, _on_axis(1.5, 1.0))
    assert torch.allclose(out, unit * intensity, rtol=1e-5, atol=1e-30)


@pytest.mark.parametrize("dtype, rtol", [(torch.float16, 2e-2), (torch.bfloat16, 1e-1)])
def test_half_precision_inputs(dtype, rtol):
    # Tolerances: the inputs themselves are rounded to 11 (float16) or 8 (bfloat16)
    # significant bits; a glossy highlight amplifies a roughness error ~4x (D ~ 1/alpha^2
    # ~ 1/r^4). Against float32 rendering of the *same rounded maps* the result is exact
    # to float32 rounding, because the work is done in float32.
    m = random_svbrdf(2, 12, roughness=(0.2, 0.9))
    scene = _on_axis(2.0, 8.0)
    ref = render(m, scene)
    half = m.to(dtype)
    out = render(half, scene)
    assert out.dtype == torch.float32
    assert torch.allclose(out, render(half.to(torch.float32), scene), rtol=1e-6, atol=1e-7)
    err = ((out - ref).abs() / (ref.abs() + 1e-3)).max()
    assert float(err) < rtol
    # Backward through the log loss (what training uses) stays finite in half precision.
    _check(half, scene, 8.0, loss=lambda x: log_radiance(x).sum())


def test_autocast_does_not_reach_inside():
    m = SVBRDF.constant(2, 9, roughness=0.0)  # a mirror: the peak would overflow float16
    scene = _on_axis(1.0, 50.0)
    ref = render(m, scene)
    for dtype in (torch.bfloat16, torch.float16):
        with torch.autocast("cpu", dtype=dtype):
            out = render(m, scene)
        assert out.dtype == torch.float32
        assert torch.allclose(out, ref, rtol=1e-6)
    assert float(ref.max()) > 65504  # the case is real: float16 could not hold it


def test_log_of_noisy_renders():
    m = random_svbrdf(1, 16)
    scene = Scene.flash(intensity=2.0, effects=list(DES18_EFFECTS) + [{"noise": {"sigma": 0.1}}])
    leaf = _leaf(m)
    noisy = render(leaf, scene)
    assert float(noisy.detach().min()) < 0  # noise pushed values below zero
    assert not torch.isfinite(torch.log(noisy + 0.01)).all()  # the naive transform breaks
    loss = log_radiance(noisy).mean()
    assert torch.isfinite(loss)
    loss.backward()
    for t in leaf.maps().values():
        assert torch.isfinite(t.grad).all() and float(t.grad.abs().max()) < 1e3


@pytest.mark.parametrize("masking", MASKING)
@pytest.mark.parametrize("fresnel", ["des18", "schlick"])
def test_gradcheck_float64_interior(masking, fresnel):
    m = random_svbrdf(1, 3, seed=5, dtype=torch.float64, roughness=(0.3, 0.8))
    scene = Scene(
        Camera(torch.tensor([0.2, -0.1, 1.8], dtype=torch.float64)),
        (PointLight(torch.tensor([[-0.3, 0.4, 1.5]], dtype=torch.float64), 3.0),),
        _effects(masking, fresnel, extra=("vignetting", "exposure", "gamma")),
    )
    maps = [t.detach().clone().requires_grad_(True) for t in m.maps().values()]

    def f(n, d, r, s):
        return render(SVBRDF(n, d, r, s, validate=False), scene)

    assert torch.autograd.gradcheck(f, maps, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_bounds_hold_with_realistic_training_configurations():
    from svbrdf_render import training_scene

    m = random_svbrdf(4, 16, roughness=(0.0, 1.0), tilt=1.5)
    scene = training_scene(4, generator=torch.Generator().manual_seed(3))
    _check(m, scene, math.pi, loss=lambda x: log_radiance(x).mean())
