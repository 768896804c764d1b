"""Vector helpers that stay finite forward and backward (docs/svbrdf-render.md, "Numerical choices")."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "safe_normalize",
    "safe_normalize_parts",
    "toward",
    "unit_and_sq",
    "dot",
    "cross_norm_sq",
    "surface_positions",
    "MIN_NORM_SQ",
]

#: Below this squared length a vector is treated as zero. ``F.normalize`` would
#: return a gradient of ~1e12 there; at ``|n| = 1e-4`` the gradient is at most 1e4.
MIN_NORM_SQ = 1e-8
_TINY = 1e-12


def safe_normalize(v: Tensor, dim: int = -1, fallback: Tensor | None = None) -> Tensor:
    """Unit vectors along ``dim``; zero-length or non-finite vectors become ``fallback``.

    ``fallback`` defaults to ``(0, 0, 1)``. The fallback pixels get a zero gradient:
    the input is sanitised *before* the square root (guard the input, not the output),
    so no NaN or inf reaches the backward pass through the unused branch.
    """
    return safe_normalize_parts(v, dim, fallback)[0]


def safe_normalize_parts(
    v: Tensor, dim: int = -1, fallback: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`safe_normalize` plus what its derivative needs: ``(unit, valid, length^2)``.

    ``valid`` marks the vectors that were normalised (not replaced by the fallback);
    ``length^2`` is 1 where they were replaced.
    """
    finite = torch.isfinite(v).all(dim=dim, keepdim=True)
    v0 = torch.where(finite, v, torch.zeros((), dtype=v.dtype, device=v.device))
    sq = (v0 * v0).sum(dim=dim, keepdim=True)
    valid = finite & (sq > MIN_NORM_SQ)
    if fallback is None:
        shape = [1] * v.dim()
        shape[dim] = v.shape[dim]
        fallback = torch.zeros(shape, dtype=v.dtype, device=v.device)
        fallback.select(dim, v.shape[dim] - 1).fill_(1.0)
    v1 = torch.where(valid, v0, fallback)
    sq1 = torch.where(valid, sq, torch.ones((), dtype=v.dtype, device=v.device))
    return v1 * torch.rsqrt(sq1), valid, sq1


def toward(pos: Tensor, w: Tensor | float, p: Tensor) -> Tensor:
    """Vector from the surface points ``p`` towards ``pos``, along dim -3.

    ``w`` is 1 for a point, 0 for a direction at infinity (then the vector is ``pos``
    itself), or a tensor of both per configuration.
    """
    if isinstance(w, float):
        return pos - p if w == 1.0 else pos.expand_as(pos)
    return pos - w * p


def unit_and_sq(vec: Tensor) -> tuple[Tensor, Tensor]:
    """``vec / |vec|`` and ``|vec|^2`` along dim -3; a zero vector stays zero.

    A zero vector (a light on the surface) gives cosines of 0, which the renderer masks.
    """
    d2 = dot(vec, vec, -3)
    return vec * torch.rsqrt(d2.clamp_min(_TINY)), d2


def dot(a: Tensor, b: Tensor, dim: int = -1) -> Tensor:
    """Dot product along ``dim``, keeping the dimension."""
    return (a * b).sum(dim=dim, keepdim=True)


def cross_norm_sq(a: Tensor, b: Tensor, dim: int = -1) -> Tensor:
    """``|a x b|^2`` along ``dim`` (3 components), keeping the dimension.

    For unit vectors this is ``1 - (a.b)^2`` without the cancellation of the subtraction,
    so it stays accurate (and non-negative) when ``a.b`` is close to 1.
    """
    ax, ay, az = (a.narrow(dim, i, 1) for i in range(3))
    bx, by, bz = (b.narrow(dim, i, 1) for i in range(3))
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return cx * cx + cy * cy + cz * cz


def surface_positions(
    height: int, width: int, *, dtype=torch.float32, device=None
) -> Tensor:
    """Pixel-centre positions on the patch ``[-1, 1]^2`` at ``z = 0``: ``(3, H, W)``.

    Row 0 is the top of the image (``y = +1``), column 0 the left (``x = -1``).
    """
    xs = (torch.arange(width, dtype=dtype, device=device) * 2 + 1) / width - 1
    ys = 1 - (torch.arange(height, dtype=dtype, device=device) * 2 + 1) / height
    y, x = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([x, y, torch.zeros_like(x)], dim=0)
