"""Noise for the procedural materials: lattice value noise, fBm, cellular (Worley) noise.

Every function works on a batch of materials at once, each with its own random tables
(drawn from its own generator by :class:`Draw`), so a batch computes what its members
compute alone, bit for bit. That holds because the batched fields use only exactly
rounded elementwise ops (``+ - * /``, ``sqrt``, ``floor``, ``min``/``max``, ``where``),
gathers and ``grid_sample``, which compute each sample on its own. Deliberately absent:

- transcendental ops (``pow``, ``exp2``, ``sigmoid``, ``atan2``, ...): torch computes them
  with a vectorised and a scalar kernel that differ in the last bit, and which elements
  take which kernel depends on the batch size and the thread count;
- fused ops (``lerp``, ``addcmul``, ``add(alpha=)``): FMA in one kernel, not the other;
- reductions over pixels: their summation order depends on the batch and the threads.

Per-material constants (angles, colours) are computed in Python floats instead.

Coordinates are in *lattice cells*: noise at frequency ``f`` cells per patch unit is
``noise(f * u, f * v)`` with ``u, v`` in patch units (the patch spans ``[-1, 1]^2``).
Lattices repeat every :data:`LATTICE_SIZE` cells.
"""

from __future__ import annotations

import colorsys
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ..seeds import Stream

__all__ = [
    "LATTICE_SIZE",
    "CELL_PERIOD",
    "Draw",
    "wrap",
    "smoothstep",
    "fract",
    "mix",
    "sample_lattice",
    "fbm",
    "worley",
    "lookup",
    "srgb_to_linear_float",
]

#: Cells of a value-noise lattice before it repeats.
LATTICE_SIZE = 64
#: Cells of a Worley (cellular) table before it repeats.
CELL_PERIOD = 64
# Bicubic interpolation reads two cells either side: lattices carry that margin, wrapped.
_PAD = 2
# Fixed per-octave rotations (golden angle) and shifts, so octaves do not line up.
_GOLDEN = math.pi * (3 - math.sqrt(5))
_OCTAVE_SHIFTS = (
    (0.0, 0.0),
    (17.3, 41.9),
    (5.1, 29.7),
    (37.7, 3.3),
    (23.9, 55.1),
    (47.1, 13.7),
    (11.3, 7.9),
    (59.3, 31.1),
)


def srgb_to_linear_float(c: float) -> float:
    """The sRGB decoding curve on one Python float (colours are picked in sRGB, stored linear)."""
    c = min(max(c, 0.0), 1.0)
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


class Draw(Stream):
    """The random choices of one material: a :class:`~svbrdf_train.data.seeds.Stream` that also
    draws the tables the noise reads (uniform tables, lattices, cell points) and colours.

    Scalars come back as Python floats, tables as tensors; all from the one ``torch.Generator``
    seeded with ``seed``, so the same seed draws the same material in any process.
    """

    def table(self, n: int, low: float = 0.0, high: float = 1.0) -> Tensor:
        """``(n,)`` uniform values, float32."""
        return low + (high - low) * torch.rand(n, generator=self.generator)

    def lattice(self, channels: int) -> Tensor:
        """``(channels, S + 4, S + 4)`` uniform values in ``[-1, 1]``, wrapped by 2 cells
        (``S = LATTICE_SIZE``): the input of :func:`sample_lattice`."""
        core = torch.rand(1, channels, LATTICE_SIZE, LATTICE_SIZE, generator=self.generator) * 2 - 1
        return F.pad(core, (_PAD, _PAD, _PAD, _PAD), mode="circular")[0]

    def cells(self, regularity: float = 0.0) -> Tensor:
        """``(2, CELL_PERIOD^2)`` feature-point offsets within their cells for :func:`worley`.

        ``regularity`` 0 scatters the points over the whole cell, 1 puts them at the centres.
        """
        jitter = torch.rand(2, CELL_PERIOD * CELL_PERIOD, generator=self.generator)
        return 0.5 + (jitter - 0.5) * (1 - regularity)

    def colour(self, hue, saturation, value) -> tuple[float, float, float]:
        """A linear RGB colour picked in sRGB HSV space; each argument a ``(low, high)`` range.

        Hue ranges may wrap (``(0.95, 1.05)`` is red).
        """
        h = self.uniform(*hue) % 1.0
        s = min(max(self.uniform(*saturation), 0.0), 1.0)
        v = min(max(self.uniform(*value), 0.0), 1.0)
        return tuple(srgb_to_linear_float(c) for c in colorsys.hsv_to_rgb(h, s, v))


# -- elementwise helpers -------------------------------------------------------------------


def wrap(t: Tensor, period: float) -> Tensor:
    """``t`` modulo ``period`` in ``[0, period)``, spelled out (``torch.remainder`` is fused)."""
    return t - torch.floor(t / period) * period


def fract(t: Tensor) -> Tensor:
    return t - torch.floor(t)


def smoothstep(edge0, edge1, x: Tensor) -> Tensor:
    """Hermite step from 0 at ``edge0`` to 1 at ``edge1`` (edges: floats or broadcastable tensors)."""
    t = ((x - edge0) / (edge1 - edge0)).clamp(0, 1)
    return t * t * (3 - 2 * t)


def mix(a, b, t: Tensor) -> Tensor:
    """``a + t (b - a)`` as separate ops (``torch.lerp`` is fused)."""
    return a + t * (b - a)


# -- value noise ---------------------------------------------------------------------------


def sample_lattice(lattice: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bicubic value noise: a smooth (C1) function through random lattice values.

    Args:
        lattice: ``(B, C, S + 4, S + 4)`` from :meth:`Draw.lattice`.
        u, v: ``(B, D, H, W)`` coordinates in cells, any range (wrapped every ``S``);
            ``D`` sets of coordinates per material (octaves, directions).

    Returns:
        ``(B, D, C, H, W)``, values roughly in ``[-1.2, 1.2]``.
    """
    b, d, h, w = u.shape
    c, p = lattice.shape[1], lattice.shape[-1]
    size = p - 2 * _PAD
    scale = 2.0 / (p - 1)  # align_corners=True: -1 and 1 are the centres of the end cells
    gx = (wrap(u, size) + _PAD) * scale - 1
    gy = (wrap(v, size) + _PAD) * scale - 1
    grid = torch.stack([gx, gy], dim=-1).reshape(b * d, h, w, 2)
    lat = lattice.unsqueeze(1).expand(b, d, c, p, p).reshape(b * d, c, p, p)
    out = F.grid_sample(lat, grid, mode="bicubic", padding_mode="border", align_corners=True)
    return out.reshape(b, d, c, h, w)


def fbm(
    lattice: Tensor,
    u: Tensor,
    v: Tensor,
    octaves: int,
    gain: float | Tensor = 0.5,
    *,
    turn: bool = True,
) -> Tensor:
    """Fractional Brownian motion: ``octaves`` of value noise, each twice the frequency.

    Args:
        lattice: ``(B, C, S + 4, S + 4)``; every octave reads it at other coordinates.
        u, v: ``(B, 1, H, W)`` coordinates of the first octave, in cells.
        gain: amplitude ratio of successive octaves; a float or ``(B, 1, 1, 1)``.
        turn: rotate each octave by the golden angle (hides the lattice); ``False`` keeps
            the axes, for anisotropic (stretched) noise.

    Returns:
        ``(B, C, H, W)``, about zero mean and standard deviation 0.5.
    """
    us, vs = [], []
    for o in range(octaves):
        f = float(2**o)
        cs, sn = (math.cos(o * _GOLDEN), math.sin(o * _GOLDEN)) if turn else (1.0, 0.0)
        sx, sy = _OCTAVE_SHIFTS[o % len(_OCTAVE_SHIFTS)]
        us.append((u * cs - v * sn) * f + sx)
        vs.append((u * sn + v * cs) * f + sy)
    n = sample_lattice(lattice, torch.cat(us, dim=1), torch.cat(vs, dim=1))
    # Octaves are independent, so dividing by the root of the summed squared amplitudes
    # keeps the single octave's standard deviation (about 0.5) whatever the gain.
    total, amp, energy = n[:, 0], 1.0, 1.0
    for o in range(1, octaves):
        amp = amp * gain
        total = total + n[:, o] * amp
        energy = energy + amp * amp
    return total / (torch.sqrt(energy) if isinstance(energy, Tensor) else math.sqrt(energy))


# -- cellular noise ------------------------------------------------------------------------


def worley(points: Tensor, u: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Cellular noise on a jittered grid: one feature point per cell, 3x3 neighbour search.

    Args:
        points: ``(B, 2, P^2)`` offsets in their cells from :meth:`Draw.cells` (``P = CELL_PERIOD``).
        u, v: ``(B, 1, H, W)`` coordinates in cells.

    Returns:
        ``f1, f2``: distances to the nearest and second nearest points, ``(B, 1, H, W)``, in
        cells; ``f2 - f1`` is about twice the distance to the cell border. ``cell``: the
        nearest point's cell, ``(B, 1, H, W)`` int64 in ``[0, P^2)`` (for :func:`lookup`).
    """
    period = CELL_PERIOD
    b = u.shape[0]
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu, v - iv
    big = torch.full_like(u, 1e4)
    f1, f2 = big, big
    cell = torch.zeros(u.shape, dtype=torch.long, device=u.device)
    px, py = points[:, 0], points[:, 1]
    for dv in (-1.0, 0.0, 1.0):
        row = wrap(iv + dv, period) * period
        for du in (-1.0, 0.0, 1.0):
            idx = (row + wrap(iu + du, period)).long()
            flat = idx.reshape(b, -1)
            dx = du + torch.gather(px, 1, flat).view_as(u) - fu
            dy = dv + torch.gather(py, 1, flat).view_as(u) - fv
            d2 = dx * dx + dy * dy
            cell = torch.where(d2 < f1, idx, cell)
            f2 = torch.minimum(f2, torch.maximum(f1, d2))
            f1 = torch.minimum(f1, d2)
    return torch.sqrt(f1), torch.sqrt(f2), cell


def lookup(table: Tensor, index: Tensor) -> Tensor:
    """Per-material table values at integer indices.

    ``table`` ``(B, N)`` or ``(B, C, N)``, ``index`` ``(B, 1, H, W)`` int64 in ``[0, N)``
    -> ``(B, 1, H, W)`` or ``(B, C, H, W)``.
    """
    b, _, h, w = index.shape
    flat = index.reshape(b, 1, h * w)
    if table.dim() == 2:
        return torch.gather(table, 1, flat[:, 0]).view(b, 1, h, w)
    c = table.shape[1]
    return torch.gather(table, 2, flat.expand(b, c, h * w)).view(b, c, h, w)
