"""The renderer: a pipeline built from the stages a scene declares.

``render(svbrdf, scene)`` evaluates, for every pixel ``p`` of the patch and every light::

    L = sum_lights  I c * [ diffuse + specular(D V F / 4) ] * cos * falloff

then runs the image stages (vignetting, exposure, noise, clip, gamma). The plan is built
by phase from the registry of :mod:`svbrdf_render.effects`, where each effect declares its
stage: the ``shading`` terms summed into the BRDF, the ``light`` factors applied per light,
the ``image`` stages on the sum. Only declared effects become stages: an undeclared effect
is absent from the computation, not multiplied by zero (the tests count the ops a render
runs to prove it).

Precision: float16/bfloat16 maps are upcast and the work runs in float32 (float64 stays
float64); the result has that compute dtype. Autocast is disabled inside, since the
GGX peak (~3.2e5 at the smallest alpha) overflows float16.

Backends: ``"eager"`` runs the stages as plain torch ops; ``"compiled"`` runs the shading
stages through ``torch.compile`` (one fused kernel per shape; the first call compiles).
"""

from __future__ import annotations

import types
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from . import fused
from .effects import EFFECTS, LightPath, Surface, effects_of_phase, resolve_effects
from .errors import MapError, SceneError
from .geometry import dot, safe_normalize, surface_positions, toward, unit_and_sq
from .maps import SVBRDF
from .scene import Scene

__all__ = ["render", "apply_image_effects", "log_radiance", "RenderPlan", "build_plan", "BACKENDS"]

BACKENDS = ("eager", "compiled")


@dataclass(frozen=True)
class _Geometry:
    """Per-configuration inputs placed for broadcasting against the maps."""

    cam: Tensor  # (..., 3, 1, 1)
    cam_w: Tensor | float  # 1 for a point camera, 0 for a directional one
    lights: tuple[tuple[Tensor, Tensor | float, Tensor], ...]  # (position, w, radiance rgb)


def _directional_weight(flag, shape: torch.Size, device, dtype) -> Tensor | float:
    if isinstance(flag, bool):
        return 0.0 if flag else 1.0
    w = (~flag).to(device=device, dtype=dtype)
    return w.expand(shape).reshape(*shape, 1, 1, 1)


def _place(t: Tensor, shape: torch.Size, channels: int, device, dtype) -> Tensor:
    """``S' + (channels,)`` -> ``S + (channels, 1, 1)``; scalars broadcast."""
    t = t.to(device=device, dtype=dtype)
    if channels == 1:
        t = t.expand(shape).unsqueeze(-1)
    else:
        t = t.expand(*shape, channels)
    return t.reshape(*shape, channels, 1, 1)


def _geometry(scene: Scene, shape: torch.Size, device, dtype) -> _Geometry:
    cam = scene.camera
    lights = []
    for light in scene.point_lights:
        rgb = _place(light.intensity, shape, 1, device, dtype) * _place(
            light.color, torch.Size(), 3, device, dtype
        )
        lights.append(
            (
                _place(light.position, shape, 3, device, dtype),
                _directional_weight(light.directional, shape, device, dtype),
                rgb,
            )
        )
    return _Geometry(
        _place(cam.position, shape, 3, device, dtype),
        _directional_weight(cam.directional, shape, device, dtype),
        tuple(lights),
    )


@dataclass(frozen=True)
class RenderPlan:
    """The stages a scene's effects declare, ready to run.

    ``stages`` lists them by name in execution order; ``shade`` runs the ``shading`` and
    ``light`` phases (what the compiled backend fuses), ``finish`` the ``image`` phase.
    """

    effects: dict[str, dict[str, Any]]
    stages: tuple[str, ...]
    shade: Callable[..., Tensor]
    finish: Callable[..., Tensor]


def _stages(fx: dict[str, dict[str, Any]], phase: str) -> list[Callable]:
    """The stages of the declared effects of ``phase``, in pipeline order, built by each
    effect's own builder (:mod:`svbrdf_render.effects`)."""
    out = []
    for name, params in effects_of_phase(fx, phase).items():
        build = EFFECTS[name].stage
        if build is not None:  # stage-less effects are parameters of the one they require
            out.append(build(params, fx))
    return out


def _build_shade(fx: dict[str, dict[str, Any]]) -> Callable[..., Tensor]:
    terms = _stages(fx, "shading")
    factors = _stages(fx, "light")

    def shade(normal, diffuse, roughness, specular, p, geo: _Geometry) -> Tensor:
        # -- surface ------------------------------------------------------------------
        n = safe_normalize(normal, dim=-3)
        v, _ = unit_and_sq(toward(geo.cam, geo.cam_w, p))
        cos_v = dot(n, v, -3)
        front = cos_v > 0
        surface = Surface(n, v, cos_v.clamp_min(0), diffuse, roughness, specular)
        brdf_terms = [prepare(surface) for prepare in terms]
        total = None
        for pos, w, rgb in geo.lights:
            # -- light geometry -----------------------------------------------------
            l, d2 = unit_and_sq(toward(pos, w, p))  # noqa: E741 - the math's name
            cos_l = dot(n, l, -3)
            visible = front & (cos_l > 0)
            light = LightPath(l, d2, cos_l.clamp_min(0), pos, w)
            # -- BRDF: the sum of the declared terms --------------------------------
            f = None
            for term in brdf_terms:
                t = term(light)
                f = t if f is None else f + t
            if f is None:  # no BRDF term declared: black
                f = torch.zeros_like(cos_l)
            # -- light factors ------------------------------------------------------
            radiance = f * rgb
            for factor in factors:
                radiance = factor(radiance, surface, light)
            zero = torch.zeros((), dtype=radiance.dtype, device=radiance.device)
            radiance = torch.where(visible, radiance, zero)
            total = radiance if total is None else total + radiance
        return total

    return shade


def _build_finish(fx: dict[str, dict[str, Any]]) -> Callable[..., Tensor]:
    stages = _stages(fx, "image")

    def finish(x: Tensor, p: Tensor, geo: _Geometry, generator) -> Tensor:
        for stage in stages:
            x = stage(x, p, geo, generator)
        return x

    return finish


_PLANS: dict[str, RenderPlan] = {}
_COMPILED: dict[str, Callable[..., Tensor]] = {}


def build_plan(effects: dict[str, dict[str, Any]]) -> RenderPlan:
    """The (cached) plan for a resolved effect declaration (``Scene.effects``)."""
    key = repr(sorted((k, sorted(v.items())) for k, v in effects.items()))
    plan = _PLANS.get(key)
    if plan is None:
        plan = RenderPlan(
            effects=effects,
            stages=tuple(effects),
            shade=_build_shade(effects),
            finish=_build_finish(effects),
        )
        _PLANS[key] = plan
    return plan


def apply_image_effects(x: Tensor, effects, *, generator: torch.Generator | None = None) -> Tensor:
    """Run the ``image`` phase of an effect declaration on rendered radiance ``x``.

    What :func:`render` does after shading, by the same stages: ``effects`` is any
    declaration :class:`Scene` takes (a scene's ``effects`` included); its ``shading`` and
    ``light`` effects are skipped, its image effects run in pipeline order. ``x`` is
    ``(..., 3, H, W)`` linear radiance; ``generator`` overrides the ``noise`` seed as in
    :func:`render`. Image effects that read the camera (vignetting) need the scene: render
    with :func:`render` for those.

    Example:
        >>> import torch
        >>> from svbrdf_render import apply_image_effects
        >>> apply_image_effects(torch.full((1, 3, 2, 2), 0.25), {"exposure": {"ev": 1.0}})[0, 0, 0, 0]
        tensor(0.5000)
    """
    image = effects_of_phase(resolve_effects(effects), "image")
    for name in image:
        if EFFECTS[name].needs_camera:
            raise SceneError(
                f"apply_image_effects: effect {name!r} reads the camera; render the scene with "
                "render() instead"
            )
    return build_plan(image).finish(x, None, None, generator)


def _is_compile_failure(exc: Exception) -> bool:
    """True for a failure of the compiler itself (no C++ toolchain, Inductor), not the inputs."""
    try:
        from torch._dynamo.exc import BackendCompilerFailed
    except ImportError:  # pragma: no cover - torch without dynamo
        return False
    return isinstance(exc, BackendCompilerFailed)


def _reason(exc: Exception) -> str:
    """One line naming why compiling failed (the backend's own exception where it has one)."""
    inner = getattr(exc, "inner_exception", None)
    exc = inner if isinstance(inner, Exception) else exc
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    name = type(exc).__name__
    if not lines:
        return name
    return lines[0] if lines[0].startswith(name) else f"{name}: {lines[0]}"


def _own_code(fn: Callable[..., Tensor]) -> Callable[..., Tensor]:
    """``fn`` with a code object of its own (same bytecode, closure and globals).

    Dynamo keeps compiled graphs, and counts them against ``recompile_limit`` (8), per
    *code object*. Every plan's ``shade`` is the same nested function with other closure
    values, so without this all plans would share one cache of 8 entries: from the ninth
    plan/shape/dtype/grad-mode combination in a process on, Dynamo would stop compiling
    and the "compiled" backend would silently run eager.
    """
    own = types.FunctionType(
        fn.__code__.replace(), fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__
    )
    own.__kwdefaults__ = fn.__kwdefaults__
    own.__qualname__ = fn.__qualname__
    return own


def _compile_with_fallback(key: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` through ``torch.compile``, cached under ``key``, falling back to ``fn``.

    ``torch.compile`` compiles lazily, so a platform that cannot compile (no C++ compiler,
    unsupported Python) fails at the first *call*; that call, and every later one under
    ``key``, then runs ``fn`` eagerly, with one warning. Compilation is static in shape
    (``dynamic=False``): new tensors of a seen shape reuse the compiled kernels; a new shape
    (or dtype, grad mode, point/directional mix) compiles once more, up to Dynamo's
    ``recompile_limit`` per function (see :func:`_own_code`).
    """
    cached = _COMPILED.get(key)
    if cached is not None:
        return cached
    try:
        compiled = torch.compile(_own_code(fn), dynamic=False)
    except Exception as e:  # pragma: no cover - platform without torch.compile
        warnings.warn(f"torch.compile unavailable ({e}); using the eager backend", stacklevel=3)
        _COMPILED[key] = fn
        return fn

    def run(*args: Any) -> Any:
        try:
            return compiled(*args)
        except Exception as e:
            if not _is_compile_failure(e):
                raise
            warnings.warn(f"torch.compile failed ({_reason(e)}); using the eager backend", stacklevel=3)
            _COMPILED[key] = fn
            return fn(*args)

    _COMPILED[key] = run
    return run


def _shade_key(plan: RenderPlan) -> str:
    # What ``shade`` depends on: plans that differ only in image effects share it.
    shading = effects_of_phase(plan.effects, "shading", "light")
    return repr([(k, sorted(v.items())) for k, v in shading.items()])


def _compiled_shade(plan: RenderPlan) -> Callable[..., Tensor]:
    """``plan.shade`` through ``torch.compile``, cached per shading configuration."""
    return _compile_with_fallback("shade" + _shade_key(plan), plan.shade)


def _compiled_des18_backward(plan: RenderPlan) -> Callable[..., tuple[Tensor, ...]]:
    """The hand-derived backward of :mod:`svbrdf_render.fused`, compiled for this plan."""
    effects = plan.effects

    def backward(grad, normal, diffuse, roughness, specular, p, geo):
        return fused.des18_shading_grads(
            effects, grad, normal, diffuse, roughness, specular, p, geo
        )

    return _compile_with_fallback("des18-backward" + _shade_key(plan), backward)


class _FusedShade(torch.autograd.Function):
    """Compiled shading whose backward recomputes instead of saving intermediates."""

    @staticmethod
    def forward(ctx, normal, diffuse, roughness, specular, p, geo, forward_fn, backward_fn):
        ctx.save_for_backward(normal, diffuse, roughness, specular)
        ctx.extra = (p, geo, backward_fn)
        return forward_fn(normal, diffuse, roughness, specular, p, geo)

    @staticmethod
    def backward(ctx, grad):
        normal, diffuse, roughness, specular = ctx.saved_tensors
        p, geo, backward_fn = ctx.extra
        grads = backward_fn(grad.contiguous(), normal, diffuse, roughness, specular, p, geo)
        return (*grads, None, None, None, None)


def _geometry_requires_grad(geo: _Geometry) -> bool:
    tensors = [geo.cam, geo.cam_w]
    for light in geo.lights:
        tensors.extend(light)
    return any(isinstance(t, Tensor) and t.requires_grad for t in tensors)


def _shade_compiled(plan: RenderPlan, maps: list[Tensor], p: Tensor, geo: _Geometry) -> Tensor:
    """The compiled backend: the hand-derived backward for the Des18 shading when only the
    maps need gradients, autograd through the compiled stages otherwise."""
    forward_fn = _compiled_shade(plan)
    if (
        fused.supports(plan.effects)
        and torch.is_grad_enabled()
        and any(m.requires_grad for m in maps)
        and not _geometry_requires_grad(geo)
    ):
        return _FusedShade.apply(*maps, p, geo, forward_fn, _compiled_des18_backward(plan))
    return forward_fn(*maps, p, geo)


def _compute_dtype(dtype: torch.dtype) -> torch.dtype:
    return torch.float64 if dtype == torch.float64 else torch.float32


def render(
    svbrdf: SVBRDF,
    scene: Scene,
    *,
    generator: torch.Generator | None = None,
    backend: str = "eager",
) -> Tensor:
    """Render a batch of materials under a scene.

    Args:
        svbrdf: maps ``(B, C, H, W)``.
        scene: camera, lights, effects; its configuration shape ``S`` is ``()``, ``(K,)``
            or ``(B, K)``.
        generator: overrides the ``noise`` effect's seed (for a different draw per call).
        backend: ``"eager"`` or ``"compiled"`` (``torch.compile`` of the shading stages).

    Returns:
        ``(B, 3, H, W)`` when ``S == ()``, else ``(B, K, 3, H, W)``; linear radiance unless
        the scene declares ``gamma``. float32 (float64 for float64 maps).

    Example:
        >>> from svbrdf_render import SVBRDF, Scene, render
        >>> img = render(SVBRDF.constant(2, 32), Scene.flash(intensity=10.0))
        >>> img.shape
        torch.Size([2, 3, 32, 32])
    """
    if not isinstance(svbrdf, SVBRDF):
        raise MapError(f"render: expected an SVBRDF, got {type(svbrdf).__name__}")
    if not isinstance(scene, Scene):
        raise TypeError(f"render: expected a Scene, got {type(scene).__name__}")
    if backend not in BACKENDS:
        raise ValueError(f"render: backend must be one of {BACKENDS}, got {backend!r}")
    shape = scene.config_shape
    b, h, w = svbrdf.shape
    if len(shape) == 2 and shape[0] not in (1, b):
        raise MapError(
            f"render: the scene has per-material configurations for {shape[0]} materials, "
            f"the SVBRDF holds {b}"
        )
    dtype = _compute_dtype(svbrdf.dtype)
    device = svbrdf.device
    with torch.autocast(device_type=device.type, enabled=False):
        maps = [m.to(dtype) for m in (svbrdf.normal, svbrdf.diffuse, svbrdf.roughness, svbrdf.specular)]
        if len(shape) > 0:
            maps = [m.unsqueeze(1) for m in maps]
        p = surface_positions(h, w, dtype=dtype, device=device)
        geo = _geometry(scene, shape, device, dtype)
        plan = build_plan(scene.effects)
        if backend == "compiled":
            radiance = _shade_compiled(plan, maps, p, geo)
        else:
            radiance = plan.shade(*maps, p, geo)
        radiance = radiance.expand(b, *radiance.shape[1:]) if radiance.shape[0] == 1 and b > 1 else radiance
        return plan.finish(radiance, p, geo, generator)



def log_radiance(x: Tensor, eps: float = 0.01) -> Tensor:
    """``log(max(x, 0) + eps)``: the transform of the log rendering loss.

    Sensor noise pushes some rendered values below zero; ``log(x + eps)`` there is NaN
    (or -inf), so the value is clamped at 0 first. The gradient is zero where it was
    clamped and at most ``1/eps`` elsewhere.
    """
    if eps <= 0:
        raise ValueError(f"log_radiance: eps must be > 0, got {eps}")
    return torch.log(x.clamp_min(0) + eps)
