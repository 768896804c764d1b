"""The renderer: a pipeline built from the stages a scene declares.

``render(svbrdf, scene)`` evaluates, for every pixel ``p`` of the patch and every light::

    L = sum_lights  I c * [ diffuse + specular(D V F / 4) ] * cos * falloff

then runs the image stages (vignetting, exposure, noise, clip, gamma). Only declared
effects become stages: an undeclared effect is absent from the computation, not
multiplied by zero (the tests count the ops a render runs to prove it).

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

from . import brdf, fused
from .errors import MapError
from .geometry import (
    cross_norm_sq,
    dot,
    safe_normalize,
    surface_positions,
    toward,
    unit_and_sq,
)
from .maps import SVBRDF
from .scene import Scene

__all__ = ["render", "log_radiance", "RenderPlan", "build_plan", "BACKENDS"]

BACKENDS = ("eager", "compiled")
_GAMMA_FLOOR = 1e-8


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

    ``stages`` lists them by name in execution order; ``shade`` and ``finish`` are the two
    phases (``shade`` is what the compiled backend fuses).
    """

    effects: dict[str, dict[str, Any]]
    stages: tuple[str, ...]
    shade: Callable[..., Tensor]
    finish: Callable[..., Tensor]


def _build_shade(fx: dict[str, dict[str, Any]]) -> Callable[..., Tensor]:
    with_diffuse = "diffuse" in fx
    spec = fx.get("specular")
    fresnel_model = fx["fresnel"]["model"] if "fresnel" in fx else None
    masking_model = fx["masking"]["model"] if "masking" in fx else None
    exact_masking = masking_model in ("smith", "height-correlated")
    with_cosine = "cosine" in fx
    falloff = fx.get("falloff")
    min_d2 = falloff["min_distance"] ** 2 if falloff else 0.0

    def shade(normal, diffuse, roughness, specular, p, geo: _Geometry) -> Tensor:
        # -- surface ------------------------------------------------------------------
        n = safe_normalize(normal, dim=-3)
        v, _ = unit_and_sq(toward(geo.cam, geo.cam_w, p))
        cos_v = dot(n, v, -3)
        front = cos_v > 0
        cv = cos_v.clamp_min(0)
        kd = brdf.diffuse_des18(diffuse, specular) if with_diffuse else None
        if spec is not None:
            alpha = brdf.alpha_from_roughness(roughness, spec["alpha_min"], spec["alpha_floor"])
            sin2_v = cross_norm_sq(n, v, -3) if exact_masking else None
        total = None
        for pos, w, rgb in geo.lights:
            # -- light geometry -----------------------------------------------------
            l, d2 = unit_and_sq(toward(pos, w, p))  # noqa: E741 - the math's name
            cos_l = dot(n, l, -3)
            visible = front & (cos_l > 0)
            cl = cos_l.clamp_min(0)
            # -- BRDF terms ---------------------------------------------------------
            f = kd
            if spec is not None:
                h, _ = unit_and_sq(l + v)
                lobe = brdf.ggx_d(dot(n, h, -3), cross_norm_sq(n, h, -3), alpha) * 0.25
                if masking_model is not None:
                    sin2_l = cross_norm_sq(n, l, -3) if exact_masking else None
                    lobe = lobe * brdf.visibility(masking_model, cl, sin2_l, cv, sin2_v, alpha)
                if fresnel_model is not None:
                    lobe = lobe * brdf.fresnel(fresnel_model, specular, dot(v, h, -3))
                else:
                    lobe = lobe * specular
                f = lobe if f is None else f + lobe
            if f is None:  # neither diffuse nor specular declared: black
                f = torch.zeros_like(cos_l)
            # -- light factors ------------------------------------------------------
            radiance = f * rgb
            if with_cosine:
                radiance = radiance * cl
            if falloff is not None and not (isinstance(w, float) and w == 0.0):
                eff_d2 = d2 if isinstance(w, float) else w * d2 + (1 - w)
                radiance = radiance / eff_d2.clamp_min(min_d2)
            zero = torch.zeros((), dtype=radiance.dtype, device=radiance.device)
            radiance = torch.where(visible, radiance, zero)
            total = radiance if total is None else total + radiance
        return total

    return shade


def _build_finish(fx: dict[str, dict[str, Any]]) -> Callable[..., Tensor]:
    stages: list[Callable[[Tensor, Tensor, _Geometry, Any], Tensor]] = []

    if "vignetting" in fx:
        strength = fx["vignetting"]["strength"]

        def vignetting(x, p, geo, gen):
            # cos of the angle between the camera axis (towards the patch centre) and the
            # ray to each pixel; 1 everywhere for a directional camera.
            v, _ = unit_and_sq(toward(geo.cam, geo.cam_w, p))
            axis, _ = unit_and_sq(geo.cam)
            c = dot(v, axis, -3).clamp(0, 1)
            c2 = c * c
            return x * (1 - strength * (1 - c2 * c2))

        stages.append(vignetting)
    if "exposure" in fx:
        gain = 2.0 ** fx["exposure"]["ev"]
        stages.append(lambda x, p, geo, gen: x * gain)
    if "noise" in fx:
        sigma, shot, seed = fx["noise"]["sigma"], fx["noise"]["shot"], fx["noise"]["seed"]

        def noise(x, p, geo, gen):
            if gen is None:
                gen = torch.Generator(device=x.device).manual_seed(seed)
            z = torch.randn(x.shape, generator=gen, dtype=x.dtype, device=x.device)
            if shot > 0:  # variance sigma^2 + shot * x, x clamped before the sqrt
                return x + z * torch.sqrt(sigma * sigma + shot * x.clamp_min(0))
            return x + z * sigma

        stages.append(noise)
    if "clip" in fx:
        top = fx["clip"]["max"]
        stages.append(lambda x, p, geo, gen: x.clamp(0, top))
    if "gamma" in fx:
        inv = 1.0 / fx["gamma"]["gamma"]
        # Clamped before the power: pow(0, 1/2.2) has an infinite slope.
        stages.append(lambda x, p, geo, gen: x.clamp_min(_GAMMA_FLOOR).pow(inv))

    def finish(x: Tensor, p: Tensor, geo: _Geometry, generator) -> Tensor:
        for stage in stages:
            x = stage(x, p, geo, generator)
        return x

    return finish


_PLANS: dict[str, RenderPlan] = {}
_COMPILED: dict[str, Callable[..., Tensor]] = {}
#: The effects ``shade`` reads (the rest are image stages, run by ``finish``).
_SHADE_EFFECTS = frozenset({"diffuse", "specular", "fresnel", "masking", "cosine", "falloff"})


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
    return repr([(k, sorted(v.items())) for k, v in plan.effects.items() if k in _SHADE_EFFECTS])


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
