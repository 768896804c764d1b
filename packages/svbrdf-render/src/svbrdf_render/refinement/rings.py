"""The flash's ring in maps: where the flash was, how much a map depends on the distance to it,
and how to take that dependence out.

A material does not know where the flash stood, so none of its maps should change, on average,
with the distance to the point under the flash. A network that saw the highlight (or the dark
falloff away from it) in a photo often stamps it into its maps all the same: a brighter or
darker disc in the diffuse, a shinier or rougher ring in roughness and specular, a bump or
dent in the normals. Around that point the patch is cut into ``RINGS`` rings of equal width
(out to the farthest pixel); per ring and channel, the mean of a map against its mean over the
whole patch says how much of the flash it carries. For normals the quantity is the radial
slope (the slope along the direction away from the point), whose ring means are 0 for relief
that does not centre on the flash.

- :func:`highlight_point` finds the point under the flash in a photo (the brightest point of a
  strongly blurred photo: the highlight of a capture parallel to the surface);
- :func:`ring_penalty` is the term :func:`svbrdf_render.refine_maps` adds to its loss;
- :func:`dering` divides the ring profile out of maps (the start of a refinement).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..geometry import surface_positions
from ..maps import SVBRDF

__all__ = ["RINGS", "WORK_SIDE", "RingBins", "dering", "find_highlight", "highlight_point", "ring_penalty"]

#: Rings of equal width from the point under the flash to the farthest pixel.
RINGS = 16
#: The maps (besides the normal's radial slope) whose ring means are held to their mean.
RING_MAPS = ("diffuse", "roughness", "specular")
#: Side of the box blur of :func:`highlight_point`, as a fraction of the photo's width: wide
#: enough that the highlight wins over bright texture.
_BLUR = 1 / 8
#: :func:`find_highlight` blurs at most this many pixels along the photo's longer side: a
#: larger photo's luminance is area-averaged down to it first, so that the search costs the
#: same at every size (a blur an eighth of a 2048 px photo wide at full size took 150 s); a
#: photo at this size or under is searched at its own, as it always was.
WORK_SIDE = 256
#: A photo shows a clear highlight when its blurred maximum is at least this many times its
#: blurred median (on unseen-dev and des18-dev, a visible highlight gives 2-60; a rough or
#: strongly textured material with none gives 1.4-1.6, with its maximum anywhere).
MIN_PEAK = 2.0
#: :func:`dering` changes a map by at most this factor (a ring of a map at 0 has no profile).
_MAX_GAIN = 4.0


def highlight_point(photo: Tensor, ignore: Tensor | None = None) -> Tensor:
    """:func:`find_highlight`'s point alone (the centre where there is no clear highlight)."""
    return find_highlight(photo, ignore)[0]


def find_highlight(photo: Tensor, ignore: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """``(B, 2)``: the patch coordinates (``x, y`` in ``[-1, 1]``, as
    :func:`~svbrdf_render.geometry.surface_positions`) of the brightest point of each photo
    ``(B, 3, H, W)`` after a box blur an eighth of its width wide: where the flash's highlight
    is in a capture parallel to the surface. A photo longer than :data:`WORK_SIDE` is searched
    at that size (area-averaged), the point read at its working pixel's centre. A photo
    without a clear highlight (its blurred maximum under :data:`MIN_PEAK` times its blurred
    median: the brightest point is then texture, anywhere) gets the centre, ``(0, 0)``, where
    a capture held over it has it.

    ``ignore``: ``(B or 1, 1, H, W)``, true where the pixels are not the material (a grey card
    or a printed strip, brighter than the material, must not pass for the flash's highlight):
    they count as black. Returns the points and ``(B,)`` whether each photo shows a clear
    highlight."""
    y = photo.float().mean(1, keepdim=True)
    if ignore is not None:
        y = y.masked_fill(ignore.to(torch.bool).to(y.device), 0.0)
    long = max(y.shape[-2:])
    if long > WORK_SIDE:  # each working pixel the mean of the photo's pixels it covers
        size = tuple(max(1, round(n * WORK_SIDE / long)) for n in y.shape[-2:])
        y = F.adaptive_avg_pool2d(y, size)
    h, w = y.shape[-2:]
    k = max(3, round(w * _BLUR)) | 1
    blurred = F.avg_pool2d(y, k, stride=1, padding=k // 2, count_include_pad=False).flatten(1)
    top, i = blurred.max(1)
    clear = (top >= MIN_PEAK * blurred.median(1).values).float()[:, None]
    rows, cols = (i // w).float(), (i % w).float()
    return torch.stack([2 * (cols + 0.5) / w - 1, 1 - 2 * (rows + 0.5) / h], dim=1) * clear, clear[:, 0] > 0


def _slopes(normal: Tensor) -> Tensor:
    """``(B, 2, HW)``: the slopes ``(x / z, y / z)`` of normals, ``z`` held at 0.05 or more."""
    return (normal[:, :2] / normal[:, 2:3].clamp_min(0.05)).flatten(2)


class RingBins:
    """The rings of a ``(B, C, H, W)`` map shape around points ``(B, 2)``: each pixel's ring,
    the pixel count of each ring, and each pixel's unit direction away from the point.

    ``exclude`` ``(B or 1, 1, H, W)``: pixels that are not the material (a reference card held
    at its own maps), left out of every ring's mean and of the map's mean: a grey card in a
    corner of a dark material would otherwise read as a ring, and the penalty would brighten
    the material around it."""

    def __init__(self, point: Tensor, shape, device=None, exclude: Tensor | None = None):
        b, _, h, w = shape
        p = surface_positions(h, w, device=device)[:2].flatten(1)  # (2, HW)
        offset = p[None] - point.to(p).expand(b, 2)[:, :, None]  # (B, 2, HW)
        r = offset.norm(dim=1)
        top = r.amax(1, keepdim=True).clamp_min(1e-6)
        self.index = (r / top * RINGS).long().clamp(max=RINGS - 1)[:, None]  # (B, 1, HW)
        ones = torch.ones_like(r[:, None])
        self.weight = None  # (B, 1, HW): 0 for the pixels left out; None: every pixel counts
        if exclude is not None:
            ones = ones * (~exclude.to(p.device, torch.bool)).flatten(2).expand(b, 1, -1).to(ones.dtype)
            self.weight = ones
        count = torch.zeros(b, 1, RINGS, device=p.device).scatter_add_(2, self.index, ones)
        self.count = count.clamp_min(1)
        self.present = (count > 0).float()
        self.away = offset / r[:, None].clamp_min(1e-6)
        # Where each pixel sits between ring centres, for a profile read back smoothly.
        t = (r / top * RINGS - 0.5).clamp(0, RINGS - 1)
        self.lo = t.floor().long()[:, None]
        self.hi = (self.lo + 1).clamp(max=RINGS - 1)
        self.frac = (t - t.floor())[:, None]

    def means(self, x: Tensor) -> Tensor:
        """``(B, C, RINGS)``: the mean of ``x`` ``(B, C, H, W)`` over each ring."""
        flat = x.flatten(2) if self.weight is None else x.flatten(2) * self.weight
        b, c, _ = flat.shape
        sums = flat.new_zeros(b, c, RINGS).scatter_add_(2, self.index.expand(b, c, -1), flat)
        return sums / self.count

    def mean(self, x: Tensor) -> Tensor:
        """``(B, C, 1)``: the mean of ``x`` over the pixels counted (all but those excluded)."""
        if self.weight is None:
            return x.flatten(2).mean(2, keepdim=True)
        return (x.flatten(2) * self.weight).sum(2, keepdim=True) / self.weight.sum(2, keepdim=True).clamp_min(1)

    def spread(self, x: Tensor) -> Tensor:
        """Mean over rings (those holding pixels) and channels of ``|ring mean - map mean|``."""
        dev = (self.means(x) - self.mean(x)).abs() * self.present
        return dev.sum(2).mean() / self.present.sum(2).mean().clamp_min(1)  # no ring counted: 0

    def radial_slope(self, normal: Tensor) -> Tensor:
        """``(B, 1, H, W)``: the slope of ``normal`` along the direction away from the point."""
        b, _, h, w = normal.shape
        return (_slopes(normal) * self.away).sum(1, keepdim=True).view(b, 1, h, w)

    def profile(self, values: Tensor) -> Tensor:
        """``(B, C, HW)``: per-ring ``values`` ``(B, C, RINGS)`` read at each pixel, linearly
        between ring centres."""
        b, c, _ = values.shape

        def at(i: Tensor) -> Tensor:
            return values.gather(2, i.expand(b, c, -1))

        return at(self.lo) * (1 - self.frac) + at(self.hi) * self.frac


def ring_penalty(maps: SVBRDF, bins: RingBins) -> Tensor:
    """How much the maps depend on the distance to the flash: :meth:`RingBins.spread` of the
    diffuse, roughness and specular maps and of the normal's radial slope, summed."""
    total = bins.spread(bins.radial_slope(maps.normal))
    for name in RING_MAPS:
        total = total + bins.spread(getattr(maps, name))
    return total


def dering(maps: SVBRDF, point: Tensor) -> SVBRDF:
    """``maps`` with the ring profile around ``point`` ``(B, 2)`` taken out: each of diffuse,
    roughness and specular multiplied, per channel, by its mean over its ring mean (read
    smoothly between rings, at most a factor 4 either way), and the normal's mean radial slope
    per ring subtracted from its slopes. Texture within a ring is kept; a map without rings
    comes back nearly unchanged."""
    bins = RingBins(point, maps.diffuse.shape, maps.device)
    out = {}
    for name in RING_MAPS:
        x = getattr(maps, name)
        gain = x.flatten(2).mean(2, keepdim=True) / bins.means(x).clamp_min(1e-4)
        gain = gain.clamp(1 / _MAX_GAIN, _MAX_GAIN)
        out[name] = (x.flatten(2) * bins.profile(gain)).clamp(0, 1).view_as(x)
    n = maps.normal
    b, _, h, w = n.shape
    slopes = _slopes(n) - bins.profile(bins.means(bins.radial_slope(n))) * bins.away
    normal = F.normalize(torch.cat([slopes, torch.ones_like(slopes[:, :1])], 1), dim=1).view(b, 3, h, w)
    return SVBRDF(normal, out["diffuse"], out["roughness"], out["specular"], validate=False)
