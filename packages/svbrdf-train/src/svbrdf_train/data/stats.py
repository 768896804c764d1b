"""Statistics of materials and their flash photos, to compare two data sets (procedural and real).

Every function takes a batch and returns one value per material (``(B,)``), or, for the pixel
histograms, a distribution (:class:`PixelHistogram`); :func:`compare` sets two sets of samples
against each other with :func:`wasserstein` (the 1-D Wasserstein distance of the per-material
values, in the statistic's unit).

Inputs follow the sample layout of :mod:`.sample`: ``photos`` ``(B, 3, H, W)`` linear,
``maps`` ``(B, 10, H, W)`` packed as ``SVBRDF.pack`` (normal 0-2, diffuse 3-5, roughness 6,
specular 7-9). Compare sets at the same resolution and field of view (both cover the surface
``[-1, 1]^2``): slopes and highlight sizes depend on both.

Definitions (all on linear values):

- *luminance*: Rec. 709 weights ``0.2126 R + 0.7152 G + 0.0722 B``;
- *saturation*: HSV saturation ``(max - min) / max`` of the RGB triple (0 for grey and black);
- *slope*: ``tan`` of the angle between the normal and ``+z``, ``|n_xy| / n_z``;
- *highlight*: the photo's luminance smoothed by a Gaussian of ``sigma`` half-widths (0.1);
  its *bright region* the pixels above half-way between the smoothed photo's 1st percentile
  and its maximum. The highlight's *size* is the bright region's share of the photo, its
  *offset* the distance from the image centre, in patch half-widths (the patch spans
  ``[-1, 1]^2``: a corner is at ``sqrt 2``), of the bright region's centroid weighted by
  the excess over that level. On the 21 des18-dev materials this centroid lies a median
  0.08 half-widths from the flash position that :func:`svbrdf_render.fit_flash` fits
  (the single brightest pixel: 0.15, pulled about by bright texture).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import SVBRDF

__all__ = [
    "LUMINANCE",
    "Statistic",
    "PixelHistogram",
    "STATISTICS",
    "luminance",
    "saturation",
    "diffuse_luminance",
    "diffuse_saturation",
    "roughness_mean",
    "roughness_histogram",
    "specular_level",
    "specular_saturation",
    "slopes",
    "slope_mean",
    "slope_p90",
    "photo_mean",
    "photo_median",
    "smoothed_luminance",
    "highlight_position",
    "highlight_offset",
    "highlight_size",
    "wasserstein",
    "summary",
    "compare",
]

#: Rec. 709 / sRGB luminance weights of linear RGB.
LUMINANCE = (0.2126, 0.7152, 0.0722)


def _check(t: Tensor, channels: int, what: str) -> Tensor:
    if t.dim() != 4 or t.shape[1] != channels:
        raise ValueError(f"{what}: expected (B, {channels}, H, W), got {tuple(t.shape)}")
    return t.detach().float()


# -- pixels ----------------------------------------------------------------------------------


def luminance(rgb: Tensor) -> Tensor:
    """``(B, 3, H, W)`` linear RGB -> ``(B, H, W)`` luminance."""
    rgb = _check(rgb, 3, "luminance")
    w = torch.tensor(LUMINANCE, dtype=rgb.dtype, device=rgb.device).view(1, 3, 1, 1)
    return (rgb * w).sum(dim=1)


def saturation(rgb: Tensor) -> Tensor:
    """``(B, 3, H, W)`` -> ``(B, H, W)`` HSV saturation ``(max - min) / max``, 0 where black."""
    rgb = _check(rgb, 3, "saturation")
    hi, lo = rgb.amax(dim=1), rgb.amin(dim=1)
    return torch.where(hi > 1e-6, (hi - lo) / hi.clamp_min(1e-6), torch.zeros_like(hi))


def _maps(maps: Tensor) -> SVBRDF:
    """The packed layout of the samples (``SVBRDF.pack``), as maps."""
    return SVBRDF.unpack(_check(maps, 10, "maps"), validate=False)


def _per_material(t: Tensor) -> Tensor:
    return t.reshape(t.shape[0], -1).mean(dim=1)


def _quantile(t: Tensor, q: float) -> Tensor:
    """Per-material quantile ``q`` of ``(B, ...)`` values (exact, by sorting)."""
    flat = t.reshape(t.shape[0], -1)
    return torch.quantile(flat, q, dim=1)


# -- maps --------------------------------------------------------------------------------------


def diffuse_luminance(maps: Tensor) -> Tensor:
    """Mean luminance of the diffuse albedo, per material (linear, 0-1)."""
    return _per_material(luminance(_maps(maps).diffuse))


def diffuse_saturation(maps: Tensor) -> Tensor:
    """Mean HSV saturation of the diffuse albedo, per material (0 grey, 1 pure colour)."""
    return _per_material(saturation(_maps(maps).diffuse))


def roughness_mean(maps: Tensor) -> Tensor:
    """Mean roughness per material (0-1, alpha = roughness^2)."""
    return _per_material(_maps(maps).roughness)


def specular_level(maps: Tensor) -> Tensor:
    """Mean luminance of the specular albedo per material (linear F0: ~0.04 dielectrics, >0.5 metals)."""
    return _per_material(luminance(_maps(maps).specular))


def specular_saturation(maps: Tensor) -> Tensor:
    """Mean HSV saturation of the specular albedo per material: 0 grey, higher is more coloured
    (gold ~0.66, copper ~0.44)."""
    return _per_material(saturation(_maps(maps).specular))


def slopes(maps: Tensor) -> Tensor:
    """Per pixel ``tan`` of the angle between the normal and ``+z``: ``(B, H, W)``."""
    n = _maps(maps).normal
    xy = torch.sqrt(n[:, 0] ** 2 + n[:, 1] ** 2)
    return xy / n[:, 2].clamp_min(1e-3)


def slope_mean(maps: Tensor) -> Tensor:
    """Mean per-pixel slope (``tan`` of the normal's angle from ``+z``) per material."""
    return _per_material(slopes(maps))


def slope_p90(maps: Tensor) -> Tensor:
    """90th percentile of the per-pixel slope per material: the steep parts of the relief."""
    return _quantile(slopes(maps), 0.9)


@dataclass(frozen=True)
class PixelHistogram:
    """A distribution of pixel values in ``[low, high]``: per material, the share of its
    pixels in each of ``bins`` equal bins; a set's distribution weighs materials equally."""

    counts: Tensor  # (B, bins), each row sums to 1
    low: float = 0.0
    high: float = 1.0

    @property
    def bins(self) -> int:
        return self.counts.shape[1]

    def pooled(self) -> Tensor:
        """``(bins,)`` the set's distribution: the mean of the materials' histograms."""
        return self.counts.mean(dim=0)

    def quantile(self, q: float) -> float:
        """Quantile ``q`` of the pooled distribution (the upper edge of the bin that reaches it)."""
        cdf = torch.cumsum(self.pooled(), 0)
        i = int(torch.searchsorted(cdf, torch.tensor(q - 1e-9, dtype=cdf.dtype)))
        i = min(i, self.bins - 1)
        return self.low + (self.high - self.low) * (i + 0.5) / self.bins


def pixel_histogram(values: Tensor, bins: int = 64, low: float = 0.0, high: float = 1.0) -> PixelHistogram:
    """Per-material histograms of ``(B, ...)`` pixel values (clamped to ``[low, high]``)."""
    flat = values.detach().float().reshape(values.shape[0], -1)
    idx = ((flat - low) / (high - low) * bins).floor().clamp(0, bins - 1).long()
    counts = torch.zeros(flat.shape[0], bins).scatter_add_(1, idx, torch.ones_like(flat))
    return PixelHistogram(counts / flat.shape[1], low, high)


def roughness_histogram(maps: Tensor, bins: int = 64) -> PixelHistogram:
    """The distribution of roughness pixel values, per material (:class:`PixelHistogram`)."""
    return pixel_histogram(_maps(maps).roughness[:, 0], bins)


# -- photos ------------------------------------------------------------------------------------


def photo_mean(photos: Tensor) -> Tensor:
    """Mean linear luminance of each photo."""
    return _per_material(luminance(photos))


def photo_median(photos: Tensor) -> Tensor:
    """Median linear luminance of each photo."""
    return _quantile(luminance(photos), 0.5)


def smoothed_luminance(photos: Tensor, sigma: float = 0.1) -> Tensor:
    """Luminance ``(B, H, W)`` blurred by a Gaussian of ``sigma`` patch half-widths
    (``sigma * W / 2`` pixels; edges replicated)."""
    lum = luminance(photos)[:, None]
    h, w = lum.shape[-2:]
    px = sigma * w / 2
    if px < 0.3:
        return lum[:, 0]
    radius = max(1, math.ceil(3 * px))
    t = torch.arange(-radius, radius + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (t / px) ** 2)
    k = k / k.sum()
    radius_h, radius_w = min(radius, h - 1), min(radius, w - 1)
    out = F.pad(lum, (radius_w, radius_w, radius_h, radius_h), mode="replicate")
    if radius_w < radius or radius_h < radius:  # tiny images: pad again to the kernel's reach
        out = F.pad(out, (radius - radius_w,) * 2 + (radius - radius_h,) * 2, mode="replicate")
    out = F.conv2d(out, k.view(1, 1, 1, -1))
    out = F.conv2d(out, k.view(1, 1, -1, 1))
    return out[:, 0]


def _bright(photos: Tensor, sigma: float, fraction: float) -> tuple[Tensor, Tensor]:
    """Smoothed luminance ``(B, H, W)`` and by how much each pixel exceeds the level
    ``fraction`` of the way from its 1st percentile to its maximum (0 below the level)."""
    s = smoothed_luminance(photos, sigma)
    flat = s.reshape(s.shape[0], -1)
    lo, hi = torch.quantile(flat, 0.01, dim=1), flat.amax(dim=1)
    level = (lo + fraction * (hi - lo)).view(-1, 1, 1)
    return s, (s - level).clamp_min(0)


def highlight_position(photos: Tensor, sigma: float = 0.1, fraction: float = 0.5) -> Tensor:
    """``(B, 2)`` surface position ``(x, y)`` of the highlight, in patch units (x right, y up,
    the centre at 0, the edges at +-1): the centroid of the smoothed luminance's excess over
    the level of :func:`highlight_size` (the brightest spot, found more steadily than by the
    single brightest pixel when texture competes with the highlight). A uniform photo has its
    highlight in the centre."""
    s, excess = _bright(photos, sigma, fraction)
    b, h, w = s.shape
    x = ((torch.arange(w, dtype=torch.float32) * 2 + 1) / w - 1).view(1, 1, w)
    y = (1 - (torch.arange(h, dtype=torch.float32) * 2 + 1) / h).view(1, h, 1)
    total = excess.sum(dim=(1, 2))
    safe = total.clamp_min(1e-12)
    cx = torch.where(total > 0, (excess * x).sum(dim=(1, 2)) / safe, torch.zeros_like(total))
    cy = torch.where(total > 0, (excess * y).sum(dim=(1, 2)) / safe, torch.zeros_like(total))
    return torch.stack([cx, cy], dim=1)


def highlight_offset(photos: Tensor, sigma: float = 0.1, fraction: float = 0.5) -> Tensor:
    """Distance of the highlight (:func:`highlight_position`) from the image centre, in patch
    half-widths."""
    return highlight_position(photos, sigma, fraction).norm(dim=1)


def highlight_size(photos: Tensor, sigma: float = 0.1, fraction: float = 0.5) -> Tensor:
    """Share of the photo (0-1) brighter, once smoothed, than ``fraction`` of the way from its
    1st percentile to its maximum: small for a sharp highlight, large for a broad one or a
    matte surface under the flash's gentle falloff."""
    _, excess = _bright(photos, sigma, fraction)
    return (excess > 0).float().flatten(1).mean(dim=1)


# -- distances ---------------------------------------------------------------------------------


def wasserstein(a, b) -> float:
    """1-D Wasserstein (earth mover's) distance between the empirical distributions of the
    values ``a`` and ``b`` (any lengths): ``integral |F_a(x) - F_b(x)| dx``, in their unit.
    0 for the same distribution; a shift by ``c`` gives ``|c|``."""
    a = torch.as_tensor(a, dtype=torch.float64).flatten()
    b = torch.as_tensor(b, dtype=torch.float64).flatten()
    if a.numel() == 0 or b.numel() == 0:
        raise ValueError("wasserstein: expected at least one value on each side")
    xs = torch.sort(torch.cat([a, b])).values
    a, b = torch.sort(a).values, torch.sort(b).values
    fa = torch.searchsorted(a, xs[:-1], right=True).double() / a.numel()
    fb = torch.searchsorted(b, xs[:-1], right=True).double() / b.numel()
    return float(((fa - fb).abs() * (xs[1:] - xs[:-1])).sum())


def histogram_wasserstein(p: PixelHistogram, q: PixelHistogram) -> float:
    """1-D Wasserstein distance between two pooled pixel distributions, in the values' unit."""
    if p.bins != q.bins or (p.low, p.high) != (q.low, q.high):
        raise ValueError("histogram_wasserstein: the histograms have different bins")
    width = (p.high - p.low) / p.bins
    cdf = torch.cumsum(p.pooled().double() - q.pooled().double(), 0)
    return float(cdf.abs().sum() * width)


# -- the table -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Statistic:
    """One row of the comparison: a per-material value of a batch, or a pixel histogram."""

    name: str
    unit: str
    of: str  # "maps" or "photos"
    function: Callable[[Tensor], Any]
    description: str = ""


STATISTICS: tuple[Statistic, ...] = (
    Statistic(
        "diffuse luminance", "linear", "maps", diffuse_luminance, "mean luminance of the diffuse albedo"
    ),
    Statistic("diffuse saturation", "0-1", "maps", diffuse_saturation, "mean HSV saturation of the diffuse"),
    Statistic("roughness mean", "0-1", "maps", roughness_mean, "mean roughness per material"),
    Statistic(
        "roughness pixels", "0-1", "maps", roughness_histogram, "histogram of all roughness pixels (64 bins)"
    ),
    Statistic("specular level", "linear", "maps", specular_level, "mean luminance of the specular albedo"),
    Statistic(
        "specular saturation", "0-1", "maps", specular_saturation, "mean HSV saturation of the specular"
    ),
    Statistic("slope mean", "tan", "maps", slope_mean, "mean tan of the normal's angle from +z"),
    Statistic("slope p90", "tan", "maps", slope_p90, "90th percentile of that tan per material"),
    Statistic("photo mean", "linear", "photos", photo_mean, "mean luminance of the linear photo"),
    Statistic("photo median", "linear", "photos", photo_median, "median luminance of the linear photo"),
    Statistic(
        "highlight size",
        "area share",
        "photos",
        highlight_size,
        "share of the photo above half-way from p1 to max",
    ),
    Statistic(
        "highlight offset",
        "half-widths",
        "photos",
        highlight_offset,
        "distance of the bright region's centroid from the centre",
    ),
)


@dataclass
class Row:
    """One statistic of two sets: summaries and the distance between their distributions."""

    name: str
    unit: str
    description: str
    first: dict[str, float]
    second: dict[str, float]
    distance: float
    values: dict[str, list[float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "description": self.description,
            "procedural": self.first,
            "real": self.second,
            "wasserstein": self.distance,
            "values": self.values,
        }


def summary(values) -> dict[str, float]:
    """Mean and the 10th, 50th and 90th percentiles of per-material values."""
    v = torch.as_tensor(values, dtype=torch.float64).flatten()
    q = torch.quantile(v, torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64))
    return {"mean": float(v.mean()), "p10": float(q[0]), "p50": float(q[1]), "p90": float(q[2])}


def _histogram_summary(h: PixelHistogram) -> dict[str, float]:
    centres = h.low + (h.high - h.low) * (torch.arange(h.bins, dtype=torch.float64) + 0.5) / h.bins
    mean = float((h.pooled().double() * centres).sum())
    return {"mean": mean, "p10": h.quantile(0.1), "p50": h.quantile(0.5), "p90": h.quantile(0.9)}


def compare(
    first: dict[str, Tensor],
    second: dict[str, Tensor],
    statistics: Sequence[Statistic] = STATISTICS,
) -> list[Row]:
    """Every statistic on two sets (``{"input": photos, "maps": maps}`` each): their
    summaries and the 1-D Wasserstein distance between their distributions (of per-material
    values, or of pooled pixels for histograms), in the statistic's unit."""
    rows = []
    for s in statistics:
        key = "maps" if s.of == "maps" else "input"
        a, b = s.function(first[key]), s.function(second[key])
        if isinstance(a, PixelHistogram):
            first_summary, second_summary = _histogram_summary(a), _histogram_summary(b)
            distance, values = histogram_wasserstein(a, b), {}
        else:
            first_summary, second_summary = summary(a), summary(b)
            distance = wasserstein(a, b)
            values = {"procedural": [float(x) for x in a], "real": [float(x) for x in b]}
        rows.append(Row(s.name, s.unit, s.description, first_summary, second_summary, distance, values))
    return rows
