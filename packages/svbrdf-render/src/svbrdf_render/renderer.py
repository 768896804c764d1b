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

The stages are public, and pass each other typed values (:mod:`svbrdf_render.stages`):
:func:`place_scene` places the scene on the patch (a :class:`~svbrdf_render.stages.SceneGeometry`),
the plan's ``shade`` turns the maps and that geometry into radiance, its ``finish`` runs the
image effects on it. :func:`render` runs the three; :func:`apply_image_effects` runs the last
alone.

Backends: ``"eager"`` runs the stages as plain torch ops; ``"compiled"`` runs the shading
stage through ``torch.compile`` (:mod:`svbrdf_render.compiled`: one fused kernel per shape; the
first call compiles).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from .compiled import shade_compiled
from .effects import EFFECTS, LightPath, Surface, effects_of_phase, resolve_effects
from .errors import MapError, SceneError
from .geometry import dot, safe_normalize, surface_positions, toward, unit_and_sq
from .maps import SVBRDF
from .scene import Scene
from .stages import FinishStage, SceneGeometry, ShadeStage

__all__ = [
    "render",
    "apply_image_effects",
    "log_radiance",
    "place_scene",
    "RenderPlan",
    "build_plan",
    "BACKENDS",
]

BACKENDS = ("eager", "compiled")


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


def place_scene(scene: Scene, height: int, width: int, *, dtype: torch.dtype, device) -> SceneGeometry:
    """The first stage: ``scene`` placed on a patch of ``height x width`` pixels, its camera and
    lights shaped to broadcast against maps of its configuration shape, in ``dtype`` on ``device``
    (the compute dtype and the maps' device of :func:`render`)."""
    positions = surface_positions(height, width, dtype=dtype, device=device)
    shape = scene.config_shape
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
    return SceneGeometry(
        positions,
        _place(cam.position, shape, 3, device, dtype),
        _directional_weight(cam.directional, shape, device, dtype),
        tuple(lights),
    )


@dataclass(frozen=True)
class RenderPlan:
    """The stages a scene's effects declare, ready to run.

    ``stages`` lists the effects by name in execution order; ``shade`` runs the ``shading`` and
    ``light`` phases (what the compiled backend fuses), ``finish`` the ``image`` phase (see
    :mod:`svbrdf_render.stages` for what each takes).
    """

    effects: dict[str, dict[str, Any]]
    stages: tuple[str, ...]
    shade: ShadeStage
    finish: FinishStage


def _stages(fx: dict[str, dict[str, Any]], phase: str) -> list[Callable]:
    """The stages of the declared effects of ``phase``, in pipeline order, built by each
    effect's own builder (:mod:`svbrdf_render.effects`)."""
    out = []
    for name, params in effects_of_phase(fx, phase).items():
        build = EFFECTS[name].stage
        if build is not None:  # stage-less effects are parameters of the one they require
            out.append(build(params, fx))
    return out


def _build_shade(fx: dict[str, dict[str, Any]]) -> ShadeStage:
    terms = _stages(fx, "shading")
    factors = _stages(fx, "light")

    def shade(normal, diffuse, roughness, specular, geometry: SceneGeometry) -> Tensor:
        p = geometry.positions
        # -- surface ------------------------------------------------------------------
        n = safe_normalize(normal, dim=-3)
        v, _ = unit_and_sq(toward(geometry.camera, geometry.camera_w, p))
        cos_v = dot(n, v, -3)
        front = cos_v > 0
        surface = Surface(n, v, cos_v.clamp_min(0), diffuse, roughness, specular)
        brdf_terms = [prepare(surface) for prepare in terms]
        total = None
        for pos, w, rgb in geometry.lights:
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


def _build_finish(fx: dict[str, dict[str, Any]]) -> FinishStage:
    stages = _stages(fx, "image")

    def finish(x: Tensor, geometry: SceneGeometry | None = None, generator=None) -> Tensor:
        for stage in stages:
            x = stage(x, geometry, generator)
        return x

    return finish


_PLANS: dict[str, RenderPlan] = {}


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
    return build_plan(image).finish(x, None, generator)


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
        geometry = place_scene(scene, h, w, dtype=dtype, device=device)
        plan = build_plan(scene.effects)
        if backend == "compiled":
            radiance = shade_compiled(plan.effects, plan.shade, maps, geometry)
        else:
            radiance = plan.shade(*maps, geometry)
        radiance = radiance.expand(b, *radiance.shape[1:]) if radiance.shape[0] == 1 and b > 1 else radiance
        return plan.finish(radiance, geometry, generator)



def log_radiance(x: Tensor, eps: float = 0.01) -> Tensor:
    """``log(max(x, 0) + eps)``: the transform of the log rendering loss.

    Sensor noise pushes some rendered values below zero; ``log(x + eps)`` there is NaN
    (or -inf), so the value is clamped at 0 first. The gradient is zero where it was
    clamped and at most ``1/eps`` elsewhere.
    """
    if eps <= 0:
        raise ValueError(f"log_radiance: eps must be > 0, got {eps}")
    return torch.log(x.clamp_min(0) + eps)
