"""Hand-derived backward pass of the Des18 shading, for the compiled backend.

Autograd through ``torch.compile`` saves ~40 full-size intermediates per render and reads
them back in the backward pass; on a CPU that traffic is most of the time. For the
Deschaintre 2018 effect set (what the rendering loss uses) the derivatives are short, so
this module recomputes the shading in the backward pass and applies them directly, in
one fused kernel that saves nothing but the inputs.

Per light, configuration, pixel and channel ``c`` (``w`` the upstream gradient times the
light's ``I c / d^2``, masked where the light or the camera is below the surface)::

    L_c = w_c f_c cos_l,   f_c = d_c (1 - s_c) / pi + D V F_c / 4
    dL/dd_c = w_c cos_l (1 - s_c) / pi
    dL/ds_c = w_c cos_l (-d_c / pi + D V (1 - e) / 4)          F = s + (1 - s) e
    dL/dalpha = S V dD/dalpha + S D dV/dalpha                  S = sum_c w_c cos_l F_c / 4
    dL/dn = (P + S D dV/dcos_l) l + S D dV/dcos_v v + S V dD/dt (2 a2 (n.h) h + 2 (n - (n.h) h))

with ``t = (n.h)^2 a2 + |n x h|^2``, ``D = a2 / (pi t^2)``, ``V = 1/(G_l G_v)``,
``G_w = cos_w (1 - k) + k``, ``k = alpha/2``, ``P = sum_c w_c f_c``; then through the
normalisation of ``n`` and the roughness remap. ``tests/test_backends.py`` checks every
gradient against autograd.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import torch
from torch import Tensor

from .effects import DES18_EFFECTS, effects_of_phase
from .geometry import cross_norm_sq, dot, safe_normalize_parts, toward, unit_and_sq

__all__ = ["supports", "des18_shading_grads"]

_TINY = 1e-12
_DES18 = frozenset(DES18_EFFECTS)


def supports(effects: dict[str, dict[str, Any]]) -> bool:
    """Whether these resolved effects shade as the Des18 set this module differentiates:
    exactly its shading and light effects (image effects run after, by autograd), with
    the Des18 Fresnel and Schlick-GGX masking."""
    shading = effects_of_phase(effects, "shading", "light")
    return (
        set(shading) == _DES18
        and shading["fresnel"]["model"] == "des18"
        and shading["masking"]["model"] == "schlick-ggx"
    )


def _alpha(roughness, alpha_min: float, floor: str):
    """GGX alpha from roughness and its derivative (``brdf.alpha_from_roughness``)."""
    r2 = roughness * roughness
    if floor == "remap":
        return alpha_min + (1.0 - alpha_min) * r2, 2.0 * (1.0 - alpha_min) * roughness
    alpha = r2.clamp_min(alpha_min)
    return alpha, torch.where(r2 >= alpha_min, 2.0 * roughness, torch.zeros_like(roughness))


class _Surface(NamedTuple):
    """The per-render quantities every light's gradient reads."""

    n: Tensor
    v: Tensor
    front: Tensor  # n.v > 0
    cv: Tensor  # max(n.v, 0)
    alpha: Tensor
    a2: Tensor
    k: Tensor  # alpha / 2
    g_v: Tensor  # cv (1 - k) + k
    diffuse: Tensor
    specular: Tensor
    one_minus_s: Tensor
    kd: Tensor  # d (1 - s) / pi


def _light_grads(s: _Surface, grad, light, p, min_d2: float):
    """The gradients ``(d, s, alpha, n)`` of one light's term (module docstring)."""
    pos, w, rgb = light
    n, v, a2, k, g_v = s.n, s.v, s.a2, s.k, s.g_v
    l, d2 = unit_and_sq(toward(pos, w, p))  # noqa: E741 - the math's name
    cos_l = dot(n, l, -3)
    visible = s.front & (cos_l > 0)
    cl = cos_l.clamp_min(0)
    h, _ = unit_and_sq(l + v)
    nh = dot(n, h, -3)
    t = nh * nh * a2 + cross_norm_sq(n, h, -3)
    t2 = (t * t).clamp_min(_TINY)
    D = a2 / (math.pi * t2)
    g_l = cl * (1 - k) + k
    V = 1.0 / (g_l * g_v)
    vh = dot(v, h, -3)
    e = torch.exp2((-5.55473 * vh - 6.98316) * vh)
    F = s.specular + s.one_minus_s * e
    if isinstance(w, float):
        eff_d2 = d2 if w == 1.0 else None
    else:
        eff_d2 = w * d2 + (1 - w)
    gm = torch.where(visible, grad, torch.zeros((), dtype=grad.dtype, device=grad.device)) * rgb
    if eff_d2 is not None:
        gm = gm / eff_d2.clamp_min(min_d2)
    wc = gm * cl
    dv = D * V
    gd = wc * s.one_minus_s * (1.0 / math.pi)
    gs = wc * (dv * (1 - e) * 0.25 - s.diffuse * (1.0 / math.pi))
    S = dot(wc, F, -3) * 0.25
    P = dot(gm, s.kd + dv * F * 0.25, -3)
    dD_dt = torch.where(t * t > _TINY, -2.0 * D / t, torch.zeros_like(t))
    dD_da2 = D / a2 + dD_dt * nh * nh
    dV_dk = -V * ((1 - cl) / g_l + (1 - s.cv) / g_v)
    ga = S * (V * dD_da2 * 2 * s.alpha + D * dV_dk * 0.5)
    sv_dt = S * V * dD_dt
    gn = (
        (P - S * dv * (1 - k) / g_l) * l
        - (S * dv * (1 - k) / g_v) * v
        + (sv_dt * 2 * a2 * nh) * h
        + (sv_dt * 2) * (n * dot(h, h, -3) - nh * h)
    )
    return gd, gs, ga, gn


def des18_shading_grads(effects, grad, normal, diffuse, roughness, specular, geometry):
    """Gradients of ``sum(grad * shade(...))`` with respect to the four maps, under ``geometry``
    (the :class:`~svbrdf_render.stages.SceneGeometry` the shading stage took)."""
    p = geometry.positions
    spec = effects["specular"]
    min_d2 = effects["falloff"]["min_distance"] ** 2

    # -- surface (as in the forward pass) ---------------------------------------------------
    n, valid, sq = safe_normalize_parts(normal, dim=-3)
    v, _ = unit_and_sq(toward(geometry.camera, geometry.camera_w, p))
    cos_v = dot(n, v, -3)
    cv = cos_v.clamp_min(0)
    alpha, dalpha_dr = _alpha(roughness, spec["alpha_min"], spec["alpha_floor"])
    k = 0.5 * alpha
    one_minus_s = 1 - specular
    s = _Surface(
        n, v, cos_v > 0, cv, alpha, alpha * alpha, k, cv * (1 - k) + k,
        diffuse, specular, one_minus_s, diffuse * one_minus_s * (1.0 / math.pi),
    )
    g_d = g_s = g_alpha = g_n = None
    for light in geometry.lights:
        gd, gs, ga, gn = _light_grads(s, grad, light, p, min_d2)
        g_d = gd if g_d is None else g_d + gd
        g_s = gs if g_s is None else g_s + gs
        g_alpha = ga if g_alpha is None else g_alpha + ga
        g_n = gn if g_n is None else g_n + gn

    # -- through the normalisation of n and the roughness remap -----------------------------
    g_n = g_n.sum_to_size(normal.shape)
    radial = dot(g_n, n, -3)
    inv_len = torch.rsqrt(sq)  # sq is 1 where the fallback normal was used
    zero = torch.zeros((), dtype=normal.dtype, device=normal.device)
    g_normal = torch.where(valid, (g_n - radial * n) * inv_len, zero)
    g_rough = (g_alpha * dalpha_dr).sum_to_size(roughness.shape)
    return (
        g_normal,
        g_d.sum_to_size(diffuse.shape),
        g_rough,
        g_s.sum_to_size(specular.shape),
    )
