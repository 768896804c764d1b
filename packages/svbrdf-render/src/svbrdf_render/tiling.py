"""Tileable maps: opposite edges that match, for materials that repeat on a surface.

Method: a cross-fade with a copy shifted by half a period, in a band at the borders only,
one axis at a time::

    x' = w(i) * x + (1 - w(i)) * roll(x, W // 2)          along x, then the same along y

The shifted copy wraps without a seam at the border (its first and last columns are the
original's two middle columns, which are neighbours) and has its own seam in the middle, where
``w = 1`` shows the original. ``w`` is a smoothstep of the distance ``d`` (in pixels) from the
nearest border: 0 on the border pixels, 1 from ``d = blend * side`` inward. So

- across the wrap seam the output shows pairs of the original's neighbouring pixels (blends of
  them near the corners): the seam looks like any other step of the map;
- the centre ``[b, side - 1 - b]`` on both axes (``b = round(blend * side)``) is the original,
  pixel for pixel: 25 % of the area at the default ``blend = 0.25``;
- every output value is a convex combination of input values of the same channel, so maps in
  ``[0, 1]`` stay there without a clamp;
- all four maps use the same weights and shifts, so each output pixel blends the same source
  pixels in every map; normals are blended as vectors and renormalised (two exactly opposite
  normals blended half and half give ``(0, 0, 1)``, with a zero gradient).

Doing the axes one after the other matters: one weight ``w(x) * w(y)`` with a copy shifted on
both axes would show that copy's horizontal seam on the left and right borders.

Artefacts (what an artist will see):

- ghosting in the band: two copies of the material show through each other (four at the
  corners); a straight feature that crosses the band fades out as another fades in;
- loss of contrast in the band: the blend keeps the mean of the two copies but not their
  variance; for unrelated content the variance falls by ``w^2 + (1 - w)^2``, to half where
  ``w = 1/2``; the map looks flatter, a little blurred, along its borders;
- a low-frequency difference between the centre and the borders (a lighting gradient of a
  scan) becomes a smooth rise and fall over the band instead of a step at the seam;
- the global mean is kept only in expectation: it moves by the band's share of
  ``mean(centre) - mean(borders)``: about 0 for a uniform material; on 30 real materials
  (``benchmarks/tiling.py``) a median of 0.0005-0.003 per map and at most 0.03 per channel.

Why this and not a gradient-domain fix (Moisan's periodic + smooth decomposition, a Poisson
solve): that one keeps every gradient but changes every pixel by a smooth field, which can
leave ``[0, 1]`` (a clamp then), and leaves high-frequency features cut at the seam (a brick
edge ends at the border); the cross-fade leaves the middle untouched and makes the seam
itself a genuine pair of neighbours, at the price of ghosting in the band.

``blend`` is the band's width as a fraction of the side, at each border, in ``(0, 0.5]``;
0.5 is the classic whole-map cross-fade (only the two middle rows and columns kept).
The default 0.25 spreads a mismatch between centre and borders over a quarter of the side
(64 px at 256 px), where a narrower band makes it a visible frame, and keeps the centre
quarter of the area exact.

:func:`seam_error` measures the result; see its docstring.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .errors import MapError
from .geometry import safe_normalize
from .maps import SVBRDF

__all__ = ["DEFAULT_BLEND", "MIN_TILEABLE_SIDE", "make_tileable", "make_tileable_map", "seam_error"]

#: The band's width as a fraction of the side, at each border (see the module docstring).
DEFAULT_BLEND = 0.25
#: Maps with a side below this are refused. At 64 px the default band is 16 px wide, so even a
#: full-range mismatch (0 against 1) between centre and border adds at most 1.5 / 16 ~ 0.09
#: per pixel step (the smoothstep's steepest slope over the band); narrower bands turn it into
#: a visible frame, and a map that small repeats so often on a surface that it shows anyway.
MIN_TILEABLE_SIDE = 64
#: Guard of the seam error's denominator: a map without any step (constant) scores 0.
_TINY = 1e-12


def _band_pixels(side: int, blend: float) -> int:
    """Band width in pixels: ``round(blend * side)``, kept in ``[1, side // 2 - 1]`` so the
    shifted copy's middle seam (between pixels ``side//2 - 1`` and ``side//2``) gets ``w = 1``."""
    return min(max(1, round(blend * side)), side // 2 - 1)


def _weight(side: int, band: int, like: Tensor) -> Tensor:
    """Weight of the original along one axis: smoothstep of the distance to the nearest border,
    0 on the border pixels, 1 from ``band`` pixels inward. ``(side,)``."""
    i = torch.arange(side, device=like.device, dtype=like.dtype)
    d = torch.minimum(i, side - 1 - i)
    t = (d / band).clamp(0, 1)
    return t * t * (3 - 2 * t)


def _check(what: str, x: Tensor, blend: float) -> None:
    if x.dim() != 4 or not x.is_floating_point():
        raise MapError(
            f"{what}: expected a floating-point (B, C, H, W) tensor, got {tuple(x.shape)} {x.dtype}"
        )
    h, w = x.shape[-2:]
    if min(h, w) < MIN_TILEABLE_SIDE:
        raise MapError(
            f"{what}: the maps are {w}x{h}, smaller than {MIN_TILEABLE_SIDE} px "
            "(MIN_TILEABLE_SIDE): too few pixels for a blend band; make them tileable at a "
            "larger size and resize after"
        )
    if not 0 < blend <= 0.5:
        raise MapError(
            f"{what}: blend is {blend!r}; expected a fraction of the side in (0, 0.5] "
            f"(the default is {DEFAULT_BLEND})"
        )


def make_tileable_map(x: Tensor, blend: float = DEFAULT_BLEND) -> Tensor:
    """One map made tileable: ``(B, C, H, W)`` -> ``(B, C, H, W)``, same dtype and device.

    Channels are blended independently (no renormalisation: use :func:`make_tileable` for a
    material, or renormalise a normal map yourself). Differentiable; each output value is a
    convex combination of input values of its channel.

    Args:
        x: ``(B, C, H, W)`` floating point, both sides at least :data:`MIN_TILEABLE_SIDE`.
        blend: band width as a fraction of the side, at each border, in ``(0, 0.5]``.

    Raises:
        MapError: not a 4-d float tensor, a side below :data:`MIN_TILEABLE_SIDE`, or ``blend``
            outside ``(0, 0.5]``.

    Example:
        >>> x = torch.linspace(0, 1, 128).expand(1, 1, 128, 128)   # a ramp: a hard seam
        >>> float(seam_error(x)) > 50, float(seam_error(make_tileable_map(x))) < 2
        (True, True)
    """
    _check("make_tileable_map", x, blend)
    h, w = x.shape[-2:]
    wx = _weight(w, _band_pixels(w, blend), x)
    x = wx * x + (1 - wx) * torch.roll(x, w // 2, dims=-1)
    wy = _weight(h, _band_pixels(h, blend), x)[:, None]
    return wy * x + (1 - wy) * torch.roll(x, h // 2, dims=-2)


def make_tileable(svbrdf: SVBRDF, *, blend: float = DEFAULT_BLEND) -> SVBRDF:
    """A material whose four maps tile: the same blend on every map, normals renormalised.

    See the module docstring for the method, its artefacts and the default. Diffuse,
    roughness and specular stay in ``[0, 1]`` without a clamp (convex combinations); zero or
    non-finite blended normals become ``(0, 0, 1)`` with a zero gradient.

    Args:
        svbrdf: maps with both sides at least :data:`MIN_TILEABLE_SIDE`.
        blend: band width as a fraction of the side, at each border, in ``(0, 0.5]``.

    Raises:
        MapError: a side below :data:`MIN_TILEABLE_SIDE`, or ``blend`` outside ``(0, 0.5]``.

    Example:
        >>> m = make_tileable(SVBRDF.constant(1, 64))
        >>> m.shape
        (1, 64, 64)
    """
    _check("make_tileable", svbrdf.normal, blend)
    packed = make_tileable_map(svbrdf.pack(), blend)
    return SVBRDF(
        safe_normalize(packed[:, 0:3], dim=1),
        packed[:, 3:6],
        packed[:, 6:7],
        packed[:, 7:10],
        validate=False,
    )


def seam_error(x: Tensor) -> Tensor:
    """How much the wrap seams of a ``(B, C, H, W)`` map stand out: ``(B,)``, 0 or more.

    Per axis, the RMS difference across the wrap seam (last column against first column; last
    row against first row) over the RMS difference between neighbouring pixels inside the map
    along the same axis (all channels together); the larger of the two axes. 1 means the seam
    looks like any other pixel step of the map; a tileable map scores about 1 (one row or
    column of steps against the average of all: 0.8-1.25 for a uniform noise texture, 0.5-1.9
    on real maps); a map that does not tile scores several times that (a ramp from 0 to 1
    scores its side minus one). A pattern whose steps sit on a few rows scores like those rows
    when its seam falls on one: a facade with a joint at the border scores 3 and tiles. A map
    without any step along an axis scores 0 there when its seam has none either (the
    denominator is guarded, so the result is always finite). A measure, not a loss.
    """
    if x.dim() != 4:
        raise MapError(f"seam_error: expected a (B, C, H, W) tensor, got {tuple(x.shape)}")
    if min(x.shape[-2:]) < 2:
        raise MapError(f"seam_error: the map is {x.shape[-1]}x{x.shape[-2]}; it needs 2 px per side")
    x = x.float() if not x.is_floating_point() else x

    def ratio(seam: Tensor, inside: Tensor) -> Tensor:
        s2 = seam.square().flatten(1).mean(1)
        i2 = inside.square().flatten(1).mean(1)
        return torch.sqrt(s2 / (i2 + _TINY))

    across_x = ratio(x[..., :, 0] - x[..., :, -1], x[..., :, 1:] - x[..., :, :-1])
    across_y = ratio(x[..., 0, :] - x[..., -1, :], x[..., 1:, :] - x[..., :-1, :])
    return torch.maximum(across_x, across_y)
