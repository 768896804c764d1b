"""The compiled backend computes what the eager one and the reference compute.

``backend="compiled"`` runs the shading stages through ``torch.compile``; these tests
check it against the staged eager renderer and the straightforward reference
(``render_reference``): forward values and the gradient with respect to every map, on a
shared ``(K, 3)`` point scene and on ``training_scene``'s per-material ``(B, 9)``
configurations (directional and point mixed), and that a second call with new tensors of
the same shape neither returns a stale result nor recompiles. Also: a compiler failure
falls back to eager with a warning, and each shading configuration has its own compile
cache (Dynamo's per-function recompile limit is not shared between effect sets).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

import svbrdf_render.compiled as compiled_module
from svbrdf_render import (
    DES18_EFFECTS,
    SVBRDF,
    Camera,
    PointLight,
    Scene,
    render,
    render_reference,
    training_scene,
)
from svbrdf_render.sampling import cosine_weighted_directions

pytestmark = pytest.mark.slow  # every test compiles (tens of seconds on 2 CPU cores)

B, K, SIZE = 2, 9, 32
# Compiled vs eager: the same float32 ops, fused; they agree to float32 rounding.
RTOL, GRAD_RTOL = 1e-5, 1e-5
# Against the float32 reference: its ``cos^2 (alpha^2 - 1) + 1`` loses a few more digits in
# highlights (~3e-5 relative at roughness 0.3); the float64 test below is the tight check.
REF_RTOL, REF_GRAD_RTOL = 1e-4, 2e-4
MAP_NAMES = ("normal", "diffuse", "roughness", "specular")


def _materials(seed: int, dtype=torch.float32) -> SVBRDF:
    """Random valid maps at interior points (roughness >= 0.3: the float32 reference holds).

    The reference forms ``cos^2 (alpha^2 - 1) + 1`` by subtraction, which loses digits
    in the sharp highlights of small alpha; these tests compare formulas, not that.
    """
    g = torch.Generator().manual_seed(seed)
    xy = 0.3 * torch.randn((B, 2, SIZE, SIZE), generator=g, dtype=torch.float64)
    normal = torch.cat([xy, torch.ones((B, 1, SIZE, SIZE), dtype=torch.float64)], dim=1)
    maps = SVBRDF(
        normal.to(dtype),  # not unit length: the renderers normalise
        torch.rand((B, 3, SIZE, SIZE), generator=g, dtype=torch.float64).to(dtype),
        (0.3 + 0.7 * torch.rand((B, 1, SIZE, SIZE), generator=g, dtype=torch.float64)).to(dtype),
        torch.rand((B, 3, SIZE, SIZE), generator=g, dtype=torch.float64).to(dtype),
    )
    for name in MAP_NAMES:
        getattr(maps, name).requires_grad_(True)
    return maps


def _point_configs(seed: int):
    g = torch.Generator().manual_seed(seed)
    view = cosine_weighted_directions((K,), g, high=0.5)
    view = view * (1.5 + 1.5 * torch.rand((K, 1), generator=g))
    d = 1.5 + 1.5 * torch.rand((K, 1), generator=g)
    light = cosine_weighted_directions((K,), g, high=0.5) * d
    return light, view, math.pi * d.squeeze(-1) ** 2


def _shared_scene(light, view, intensity) -> Scene:
    return Scene(Camera(view), (PointLight(light, intensity),), DES18_EFFECTS)


def _value_and_grads(fn, maps: SVBRDF, weight: torch.Tensor):
    """The rendering and d(sum(weight * rendering))/d(map) for every map."""
    out = fn(maps)
    grads = torch.autograd.grad((out * weight).sum(), [getattr(maps, n) for n in MAP_NAMES])
    return out.detach(), dict(zip(MAP_NAMES, grads, strict=True))


def _weight(shape, seed: int) -> torch.Tensor:
    # A random cotangent so that every pixel and channel matters to every gradient.
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed))


def _assert_close(actual, expected, rtol, what):
    # Relative to each tensor's scale: highlights reach ~1e2, shadows are exactly 0.
    scale = float(expected.abs().max())
    assert scale > 0, f"{what}: the expected tensor is all zero"
    assert torch.isfinite(actual).all(), f"{what}: non-finite values"
    torch.testing.assert_close(
        actual, expected, rtol=rtol, atol=rtol * scale, msg=lambda m: f"{what}: {m}"
    )


def _compile_counters():
    from torch._dynamo.utils import counters

    return dict(counters["stats"]), dict(counters["frames"])


@pytest.fixture(autouse=True)
def _no_eager_fallback():
    """A compile failure falls back to eager with a warning; here it must not happen silently."""
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message="torch.compile (failed|unavailable)")
        yield


def test_shared_scene_compiled_matches_eager_and_reference():
    light, view, intensity = _point_configs(0)
    scene = _shared_scene(light, view, intensity)
    maps = _materials(1)
    w = _weight((B, K, 3, SIZE, SIZE), 2)

    ref, g_ref = _value_and_grads(lambda m: render_reference(m, light, view, intensity), maps, w)
    eager, g_eager = _value_and_grads(lambda m: render(m, scene), maps, w)
    comp, g_comp = _value_and_grads(lambda m: render(m, scene, backend="compiled"), maps, w)

    assert comp.shape == eager.shape == ref.shape == (B, K, 3, SIZE, SIZE)
    assert comp.dtype == torch.float32
    assert (ref > 0).float().mean() > 0.5  # most pixels lit: the comparison means something
    _assert_close(comp, eager, RTOL, "compiled vs eager")
    _assert_close(eager, ref, REF_RTOL, "eager vs reference")
    _assert_close(comp, ref, REF_RTOL, "compiled vs reference")
    for n in MAP_NAMES:
        assert g_comp[n].abs().max() > 0, f"zero gradient for {n}"
        _assert_close(g_comp[n], g_eager[n], GRAD_RTOL, f"d/d{n}: compiled vs eager")
        _assert_close(g_comp[n], g_ref[n], REF_GRAD_RTOL, f"d/d{n}: compiled vs reference")
        _assert_close(g_eager[n], g_ref[n], REF_GRAD_RTOL, f"d/d{n}: eager vs reference")


def test_shared_scene_float64_agrees_tightly_with_reference():
    # In float64 the reference's cancellation is harmless: same formulas, same numbers.
    light, view, intensity = _point_configs(3)
    scene = _shared_scene(light, view, intensity)
    maps = _materials(4, torch.float64)
    w = _weight((B, K, 3, SIZE, SIZE), 5).double()

    ref, g_ref = _value_and_grads(lambda m: render_reference(m, light, view, intensity), maps, w)
    comp, g_comp = _value_and_grads(lambda m: render(m, scene, backend="compiled"), maps, w)

    assert comp.dtype == torch.float64
    _assert_close(comp, ref, 1e-10, "compiled vs reference (float64)")
    for n in MAP_NAMES:
        _assert_close(g_comp[n], g_ref[n], 1e-9, f"d/d{n}: compiled vs reference (float64)")


def test_training_scene_compiled_matches_eager():
    scene = training_scene(B, generator=torch.Generator().manual_seed(6))
    assert tuple(scene.config_shape) == (B, 9)
    flags = scene.camera.directional
    assert bool(flags.any()) and not bool(flags.all())  # directional and point mixed
    maps = _materials(7)
    w = _weight((B, 9, 3, SIZE, SIZE), 8)

    eager, g_eager = _value_and_grads(lambda m: render(m, scene), maps, w)
    comp, g_comp = _value_and_grads(lambda m: render(m, scene, backend="compiled"), maps, w)

    assert comp.shape == (B, 9, 3, SIZE, SIZE)
    _assert_close(comp, eager, RTOL, "compiled vs eager (training scene)")
    for n in MAP_NAMES:
        assert g_comp[n].abs().max() > 0, f"zero gradient for {n}"
        _assert_close(g_comp[n], g_eager[n], GRAD_RTOL, f"d/d{n}: compiled vs eager (training)")

    # The point configurations (the last 6) are what the reference computes, per material.
    pts = slice(3, 9)
    for i in range(B):
        light = scene.lights[0].position[i, pts]
        view = scene.camera.position[i, pts]
        ref = render_reference(maps[i].detach(), light, view, scene.lights[0].intensity)
        _assert_close(comp[i : i + 1, pts], ref, REF_RTOL, f"compiled vs reference, material {i}")


def test_second_call_with_new_inputs_is_fresh_and_does_not_recompile():
    light, view, intensity = _point_configs(9)
    scene = _shared_scene(light, view, intensity)
    w = _weight((B, K, 3, SIZE, SIZE), 10)
    compiled = lambda m: render(m, scene, backend="compiled")  # noqa: E731

    first_maps = _materials(11)
    first, _ = _value_and_grads(compiled, first_maps, w)
    stats_before = _compile_counters()

    # New maps and a new scene (new position tensors), same shapes.
    light2, view2, intensity2 = _point_configs(12)
    scene2 = _shared_scene(light2, view2, intensity2)
    maps = _materials(13)
    comp, g_comp = _value_and_grads(lambda m: render(m, scene2, backend="compiled"), maps, w)
    eager, g_eager = _value_and_grads(lambda m: render(m, scene2), maps, w)
    assert (comp - first).abs().max() > 1e-3 * first.abs().max()  # not the old result
    _assert_close(comp, eager, RTOL, "second call: compiled vs eager")
    for n in MAP_NAMES:
        _assert_close(g_comp[n], g_eager[n], GRAD_RTOL, f"second call d/d{n}: compiled vs eager")

    # Training-style loop: the same shapes again and again compile nothing new.
    for seed in (14, 15):
        _value_and_grads(compiled, _materials(seed), w)
    assert _compile_counters() == stats_before, "a call with same-shaped inputs recompiled"


def test_compile_failure_falls_back_to_eager_with_one_warning(monkeypatch):
    # torch.compile compiles lazily: a platform without a C++ compiler fails at the first
    # call, with BackendCompilerFailed. Simulate that without touching the real compiler.
    from torch._dynamo.exc import BackendCompilerFailed

    calls = []

    def broken_compile(fn, **kwargs):
        def compiled(*args):
            calls.append(1)
            raise BackendCompilerFailed(
                "inductor", RuntimeError("InvalidCxxCompiler: no working C++ compiler"), None
            )

        return compiled

    monkeypatch.setattr(compiled_module, "_COMPILED", {})
    monkeypatch.setattr(torch, "compile", broken_compile)
    light, view, intensity = _point_configs(16)
    scene = _shared_scene(light, view, intensity)
    maps = _materials(17)
    with pytest.warns(UserWarning, match="torch.compile failed .*InvalidCxxCompiler"):
        out = render(maps, scene, backend="compiled")
    _assert_close(out.detach(), render(maps, scene).detach(), RTOL, "fallback vs eager")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render(maps, scene, backend="compiled")  # eager from now on: no retry, no warning
    assert len(calls) == 1

    # Errors that are not the compiler's propagate unchanged.
    def failing_compile(fn, **kwargs):
        def compiled(*args):
            raise ValueError("bad input")

        return compiled

    monkeypatch.setattr(compiled_module, "_COMPILED", {})
    monkeypatch.setattr(torch, "compile", failing_compile)
    with pytest.raises(ValueError, match="bad input"):
        render(maps, scene, backend="compiled")


def test_each_shading_configuration_has_its_own_compile_cache():
    # Dynamo caches compiled graphs per code object, with a limit (8) on the entries. Every
    # plan's shade function is the same nested function; were their caches shared, a process
    # that renders a few effect sets at a few shapes would run out and silently go eager.
    # With the limit at 1, a second plan still compiles (and image effects reuse the shade).
    from torch._dynamo.utils import counters

    config = torch._dynamo.config
    limit = "recompile_limit" if hasattr(config, "recompile_limit") else "cache_size_limit"
    light, view, intensity = _point_configs(18)
    maps = _materials(19).detach()
    small = maps.crop(0, 0, 8)
    plans = [("diffuse", "cosine"), ("diffuse", "specular", "cosine")]
    with config.patch({limit: 1}), torch.no_grad():
        for effects in plans:
            scene = Scene(Camera(view), (PointLight(light, intensity),), effects)
            before = counters["stats"]["unique_graphs"]
            out = render(small, scene, backend="compiled")
            assert counters["stats"]["unique_graphs"] == before + 1, f"{effects}: not compiled"
            _assert_close(out, render(small, scene), RTOL, f"{effects}: compiled vs eager")
        before = counters["stats"]["unique_graphs"]
        scene = Scene(Camera(view), (PointLight(light, intensity),), plans[-1] + ("gamma",))
        render(small, scene, backend="compiled")
        assert counters["stats"]["unique_graphs"] == before, "an image effect recompiled shade"


@pytest.mark.parametrize("floor", ["remap", "clamp"])
def test_hand_derived_backward_matches_autograd_on_hard_cases(floor):
    # The compiled backend differentiates the Des18 shading by hand (svbrdf_render.fused);
    # at the hard cases it must give what autograd gives through the eager stages: finite,
    # zero where the fallback normal or a clamp cuts the path, equal elsewhere.
    maps = _materials(20).detach()
    n = maps.normal.clone()
    n[:, :, 0, 0] = 0.0  # zero-length
    n[:, 0, 1, 1] = float("nan")  # NaN
    n[:, :, 2, 2] = torch.tensor([1.0, 0.0, 0.0]).view(1, 3)  # perpendicular to the patch
    r = maps.roughness.clone()
    r[:, :, 3, :] = 0.0
    r[:, :, 4, :] = 1.0
    r[:, :, 5, :] = 0.01  # below the clamp floor
    hard = SVBRDF(n, maps.diffuse, r, maps.specular, validate=False)
    for name in MAP_NAMES:
        getattr(hard, name).requires_grad_(True)
    lights = torch.tensor([[0.0, 0.0, 2.0], [0.3, 0.0, 0.0], [5.0, 0.0, 0.0], [0.2, -0.1, 1.2]])
    cams = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [-4.0, 0.0, 0.1]])
    effects = {e: {} for e in DES18_EFFECTS}
    effects["specular"] = {"alpha_floor": floor}
    scene = Scene(Camera(cams), (PointLight(lights, 5.0),), effects)
    w = _weight((B, 4, 3, SIZE, SIZE), 21)
    eager, g_eager = _value_and_grads(lambda m: render(m, scene), hard, w)
    comp, g_comp = _value_and_grads(lambda m: render(m, scene, backend="compiled"), hard, w)
    _assert_close(comp, eager, RTOL, "hard cases: compiled vs eager")
    assert any(k.startswith("des18-backward") for k in compiled_module._COMPILED)  # it ran
    for name in MAP_NAMES:
        assert torch.isfinite(g_comp[name]).all(), name
        _assert_close(g_comp[name], g_eager[name], 1e-4, f"hard cases d/d{name}")
