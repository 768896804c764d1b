"""A straightforward eager implementation of the shading formulas.

This is the textbook transcription (``1 - cos^2`` style algebra, ``pow``, plain
normalisation, no guards): easy to check by eye against the papers, and the baseline the
tests compare the staged renderer with, and the benchmark times it against. It is valid
at interior points only (unit-ish normals, lights above the surface, alpha > 0); the
production renderer is what handles the hard cases.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .geometry import surface_positions
from .maps import SVBRDF

__all__ = ["render_reference"]


def _normalize(x: Tensor) -> Tensor:
    return x / torch.sqrt((x**2).sum(dim=-3, keepdim=True))


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(dim=-3, keepdim=True)


def _visibility(model: str, nl: Tensor, nv: Tensor, alpha: Tensor) -> Tensor:
    """Shadowing-masking, as ``V = G / (n.l n.v)``."""
    if model == "schlick-ggx":
        k = alpha / 2
        return 1 / (nl * (1 - k) + k) / (nv * (1 - k) + k)
    tan2_l = (1 - nl**2) / nl**2
    tan2_v = (1 - nv**2) / nv**2
    lam_l = (-1 + torch.sqrt(1 + alpha**2 * tan2_l)) / 2
    lam_v = (-1 + torch.sqrt(1 + alpha**2 * tan2_v)) / 2
    if model == "smith":
        G = 1 / (1 + lam_l) / (1 + lam_v)
    elif model == "height-correlated":
        G = 1 / (1 + lam_l + lam_v)
    else:
        raise ValueError(f"unknown masking model {model!r}")
    return G / (nl * nv)


def _fresnel(model: str, s: Tensor, v_dot_h: Tensor) -> Tensor:
    """The Fresnel factor ``F``."""
    if model == "des18":
        return s + (1 - s) * torch.pow(2.0, (-5.55473 * v_dot_h - 6.98316) * v_dot_h)
    if model == "schlick":
        return s + (1 - s) * torch.pow(1 - v_dot_h, 5)
    raise ValueError(f"unknown fresnel model {model!r}")


def render_reference(
    svbrdf: SVBRDF,
    light_pos: Tensor,
    view_pos: Tensor,
    intensity: float | Tensor = 1.0,
    *,
    fresnel_model: str = "des18",
    masking_model: str = "schlick-ggx",
    alpha_min: float = 1e-3,
) -> Tensor:
    """Render point lights/cameras at ``(K, 3)`` positions: returns ``(B, K, 3, H, W)``.

    Effects: diffuse, specular, fresnel, masking, cosine, falloff (the Des18 set), with
    the roughness remap ``alpha = alpha_min + (1 - alpha_min) r^2``.
    """
    b, h, w = svbrdf.shape
    dtype = torch.float64 if svbrdf.dtype == torch.float64 else torch.float32
    n = _normalize(svbrdf.normal.to(dtype)).unsqueeze(1)
    d = svbrdf.diffuse.to(dtype).unsqueeze(1)
    r = svbrdf.roughness.to(dtype).unsqueeze(1)
    s = svbrdf.specular.to(dtype).unsqueeze(1)
    p = surface_positions(h, w, dtype=dtype, device=svbrdf.device)
    lp = light_pos.to(dtype).reshape(-1, 3, 1, 1)
    vp = view_pos.to(dtype).reshape(-1, 3, 1, 1)
    intensity = torch.as_tensor(intensity, dtype=dtype).reshape(-1, 1, 1, 1)

    wi = lp - p
    wo = vp - p
    dist2 = (wi**2).sum(dim=-3, keepdim=True)
    l = _normalize(wi)  # noqa: E741
    v = _normalize(wo)
    hv = _normalize(l + v)
    n_dot_l = _dot(n, l)
    n_dot_v = _dot(n, v)
    n_dot_h = _dot(n, hv)
    v_dot_h = _dot(v, hv)

    alpha = alpha_min + (1 - alpha_min) * r**2
    # GGX distribution
    D = alpha**2 / (math.pi * (n_dot_h**2 * (alpha**2 - 1) + 1) ** 2)
    nl = torch.clamp(n_dot_l, min=0)
    nv = torch.clamp(n_dot_v, min=0)
    V = _visibility(masking_model, nl, nv, alpha)
    F = _fresnel(fresnel_model, s, v_dot_h)

    f = d * (1 - s) / math.pi + F * V * D / 4
    radiance = intensity * f * nl / dist2
    visible = (n_dot_l > 0) & (n_dot_v > 0)
    return torch.where(visible, radiance, torch.zeros_like(radiance))
