"""Microfacet BRDF terms as pure functions on tensors.

Symbols follow the math: ``n`` normal, ``l`` direction to the light, ``v`` direction to
the viewer, ``h`` half vector, ``alpha`` GGX width (``roughness**2``), ``s`` specular
albedo (F0), ``d`` diffuse albedo. Cosines are passed with the squared sine computed as
``|n x w|^2`` (see :func:`~svbrdf_render.geometry.cross_norm_sq`), never as ``1 - cos^2``.

Default model (the Deschaintre 2018 convention, "des18")::

    f = d (1 - s) / pi  +  F(v.h) * V(n.l, n.v) * D(n.h) / 4

with ``V = G / (n.l n.v)`` (the form where ``1/(n.l n.v)`` cancels):

=================  ==================================================================
term               models
=================  ==================================================================
``D``              GGX / Trowbridge-Reitz
``V`` (masking)    ``schlick-ggx`` (Des18, ``k = alpha/2``), ``smith`` (exact separable
                   Smith GGX, what Mitsuba 3 computes), ``height-correlated`` Smith
``F`` (fresnel)    ``des18`` (spherical-Gaussian Schlick), ``schlick`` (exact power 5)
=================  ==================================================================
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .geometry import cross_norm_sq, dot, safe_normalize

__all__ = [
    "ALPHA_MIN",
    "FRESNEL_MODELS",
    "MASKING_MODELS",
    "alpha_from_roughness",
    "ggx_d",
    "visibility",
    "visibility_schlick_ggx",
    "visibility_smith",
    "visibility_height_correlated",
    "fresnel",
    "fresnel_des18",
    "fresnel_schlick",
    "diffuse_des18",
    "evaluate",
]

#: Smallest GGX alpha. At alpha = 1e-3 the peak of D is 1/(pi alpha^2) ~ 3.2e5: finite in
#: float32 (it would overflow float16 at ~7.8e4, which is why the renderer computes in float32).
ALPHA_MIN = 1e-3
FRESNEL_MODELS = ("des18", "schlick")
MASKING_MODELS = ("schlick-ggx", "smith", "height-correlated")
_TINY = 1e-12


def alpha_from_roughness(
    roughness: Tensor, alpha_min: float = ALPHA_MIN, floor: str = "remap"
) -> Tensor:
    """GGX alpha from roughness in [0, 1], kept at or above ``alpha_min``.

    ``floor="remap"`` (default): ``alpha = alpha_min + (1 - alpha_min) r^2``. The map is
    affine in ``r^2``, so the gradient reaches every roughness above 0.
    ``floor="clamp"``: ``alpha = max(r^2, alpha_min)``; bit-identical to ``r^2`` above the
    floor but the gradient is *zero* for ``r < sqrt(alpha_min)`` (~0.032): a network that
    predicts a mirror there gets no signal from the rendering loss.
    """
    r2 = roughness * roughness
    if floor == "remap":
        return alpha_min + (1.0 - alpha_min) * r2
    if floor == "clamp":
        return r2.clamp_min(alpha_min)
    raise ValueError(f"alpha floor: expected 'remap' or 'clamp', got {floor!r}")


def ggx_d(cos_h: Tensor, sin2_h: Tensor, alpha: Tensor) -> Tensor:
    """GGX normal distribution ``D(h)`` from ``n.h`` and ``|n x h|^2``.

    ``D = alpha^2 / (pi (cos^2 alpha^2 + sin^2)^2)``: the usual
    ``cos^2 (alpha^2 - 1) + 1`` rewritten without subtracting from 1, so the peak
    ``cos = 1`` is exact for tiny alpha. The denominator is at least ``alpha^2`` for unit
    ``h``; it is guarded only against a degenerate zero-length ``h``.
    """
    a2 = alpha * alpha
    t = cos_h * cos_h * a2 + sin2_h
    return a2 / (math.pi * (t * t).clamp_min(_TINY))


def visibility_schlick_ggx(cos_l: Tensor, cos_v: Tensor, alpha: Tensor) -> Tensor:
    """Des18 Schlick-GGX visibility ``G / (n.l n.v) = 1 / ((n.l(1-k)+k)(n.v(1-k)+k))``, k = alpha/2.

    Cosines are expected clamped to ``>= 0``; the result is at most ``1/k^2``.
    """
    k = 0.5 * alpha
    return 1.0 / ((cos_l * (1 - k) + k) * (cos_v * (1 - k) + k))


def _lambda_root(cos_w: Tensor, sin2_w: Tensor, alpha: Tensor) -> Tensor:
    """``sqrt(cos^2 + alpha^2 sin^2)`` = ``cos * sqrt(1 + alpha^2 tan^2)``, finite at grazing."""
    return torch.sqrt((cos_w * cos_w + alpha * alpha * sin2_w).clamp_min(_TINY))


def visibility_smith(
    cos_l: Tensor, sin2_l: Tensor, cos_v: Tensor, sin2_v: Tensor, alpha: Tensor
) -> Tensor:
    """Exact separable Smith GGX: ``G1(l) G1(v) / (n.l n.v)``.

    ``G1(w)/cos = 2 / (cos + sqrt(cos^2 + alpha^2 sin^2))``: bounded by ``2/alpha`` at grazing.
    """
    g_l = 2.0 / (cos_l + _lambda_root(cos_l, sin2_l, alpha))
    g_v = 2.0 / (cos_v + _lambda_root(cos_v, sin2_v, alpha))
    return g_l * g_v


def visibility_height_correlated(
    cos_l: Tensor, sin2_l: Tensor, cos_v: Tensor, sin2_v: Tensor, alpha: Tensor
) -> Tensor:
    """Height-correlated Smith GGX: ``G2 / (n.l n.v) = 2 / (n.v L(l) + n.l L(v))``.

    ``L(w) = sqrt(cos^2 + alpha^2 sin^2)``. The denominator vanishes only when both
    cosines are 0; it is guarded there (the renderer masks those pixels anyway).
    """
    den = cos_v * _lambda_root(cos_l, sin2_l, alpha) + cos_l * _lambda_root(cos_v, sin2_v, alpha)
    return 2.0 / den.clamp_min(_TINY)


def visibility(
    model: str,
    cos_l: Tensor,
    sin2_l: Tensor,
    cos_v: Tensor,
    sin2_v: Tensor,
    alpha: Tensor,
) -> Tensor:
    """Dispatch to a masking model by name (see :data:`MASKING_MODELS`)."""
    if model == "schlick-ggx":
        return visibility_schlick_ggx(cos_l, cos_v, alpha)
    if model == "smith":
        return visibility_smith(cos_l, sin2_l, cos_v, sin2_v, alpha)
    if model == "height-correlated":
        return visibility_height_correlated(cos_l, sin2_l, cos_v, sin2_v, alpha)
    raise ValueError(f"masking model: expected one of {MASKING_MODELS}, got {model!r}")


def fresnel_des18(s: Tensor, cos_vh: Tensor) -> Tensor:
    """Spherical-Gaussian Schlick: ``s + (1-s) 2^((-5.55473 c - 6.98316) c)``."""
    return s + (1 - s) * torch.exp2((-5.55473 * cos_vh - 6.98316) * cos_vh)


def fresnel_schlick(s: Tensor, cos_vh: Tensor) -> Tensor:
    """Exact Schlick: ``s + (1-s)(1-c)^5`` with ``c`` clamped to ``[0, 1]``."""
    m = 1 - cos_vh.clamp(0, 1)
    m2 = m * m
    return s + (1 - s) * (m2 * m2 * m)


def fresnel(model: str, s: Tensor, cos_vh: Tensor) -> Tensor:
    """Dispatch to a Fresnel model by name (see :data:`FRESNEL_MODELS`)."""
    if model == "des18":
        return fresnel_des18(s, cos_vh)
    if model == "schlick":
        return fresnel_schlick(s, cos_vh)
    raise ValueError(f"fresnel model: expected one of {FRESNEL_MODELS}, got {model!r}")


def diffuse_des18(d: Tensor, s: Tensor) -> Tensor:
    """Lambertian term with the Des18 energy split: ``d (1 - s) / pi``."""
    return d * (1 - s) * (1.0 / math.pi)


def evaluate(
    n: Tensor,
    l: Tensor,  # noqa: E741 - the math's name
    v: Tensor,
    diffuse: Tensor,
    roughness: Tensor,
    specular: Tensor,
    *,
    fresnel_model: str | None = "des18",
    masking_model: str | None = "schlick-ggx",
    with_diffuse: bool = True,
    with_specular: bool = True,
    alpha_min: float = ALPHA_MIN,
    alpha_floor: str = "remap",
    dim: int = -1,
) -> Tensor:
    """The BRDF value ``f(l, v)`` (no cosine, no light), for directions along ``dim``.

    ``n``, ``l``, ``v`` need not be unit length. Where ``n.l <= 0`` or ``n.v <= 0`` the
    result is 0. ``fresnel_model=None`` means ``F = s``; ``masking_model=None`` means
    ``V = 1`` (implicit ``G = n.l n.v``). Shapes broadcast; albedos carry the colour
    channels along ``dim``, roughness one channel.
    """
    n = safe_normalize(n, dim=dim)
    l = safe_normalize(l, dim=dim)  # noqa: E741
    v = safe_normalize(v, dim=dim)
    h = safe_normalize(l + v, dim=dim, fallback=n)
    cos_l, cos_v, cos_h = dot(n, l, dim), dot(n, v, dim), dot(n, h, dim)
    visible = (cos_l > 0) & (cos_v > 0)
    cl, cv = cos_l.clamp_min(0), cos_v.clamp_min(0)
    alpha = alpha_from_roughness(roughness, alpha_min, alpha_floor)
    f = torch.zeros((), dtype=n.dtype, device=n.device)
    if with_diffuse:
        f = f + diffuse_des18(diffuse, specular)
    if with_specular:
        spec = ggx_d(cos_h, cross_norm_sq(n, h, dim), alpha) * 0.25
        if masking_model is not None:
            spec = spec * visibility(
                masking_model, cl, cross_norm_sq(n, l, dim), cv, cross_norm_sq(n, v, dim), alpha
            )
        spec = spec * (fresnel(fresnel_model, specular, dot(v, h, dim)) if fresnel_model else specular)
        f = f + spec
    return torch.where(visible, f, torch.zeros((), dtype=f.dtype, device=f.device))
