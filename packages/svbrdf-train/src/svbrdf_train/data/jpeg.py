"""A JPEG round trip in torch: what a phone's JPEG does to a linear photo, without a codec.

:func:`jpeg_roundtrip` takes linear photos ``(B, 3, H, W)`` in ``[0, 1]`` through what a
baseline JPEG encoder and decoder do to them and back to linear: sRGB encoding to 8 bits,
RGB to YCbCr (JFIF, full range), chroma subsampled 2x2 (4:2:0, as phones save), 8x8 block
DCT quantised with the standard luminance and chrominance tables (ITU T.81, Annex K) scaled
by the quality as libjpeg scales them, then the inverse of each step, rounded to 8 bits as a
decoder's output is, and sRGB decoded to linear. Images whose sides are not multiples of the
block size are padded by repeating the edge, as encoders do, and cropped back.

It is not a codec (no entropy coding: it changes no pixel value), and not libjpeg's bytes
(libjpeg's integer DCT and its "fancy" chroma upsampling round differently), but it makes the
errors JPEG makes: 8x8 blocking, ringing at edges, lost fine texture and bled colour, more of
them at lower quality. Pure torch ops with no randomness, each sample on its own: the same
output on every call, in any batch, on the device of the input.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_models.errors import DataError

__all__ = ["LUMINANCE_TABLE", "CHROMINANCE_TABLE", "quantisation_table", "jpeg_roundtrip"]

#: ITU T.81 Annex K.1: the standard luminance quantisation table (quality 50), row major.
LUMINANCE_TABLE = (
    (16, 11, 10, 16, 24, 40, 51, 61),
    (12, 12, 14, 19, 26, 58, 60, 55),
    (14, 13, 16, 24, 40, 57, 69, 56),
    (14, 17, 22, 29, 51, 87, 80, 62),
    (18, 22, 37, 56, 68, 109, 103, 77),
    (24, 35, 55, 64, 81, 104, 113, 92),
    (49, 64, 78, 87, 103, 121, 120, 101),
    (72, 92, 95, 98, 112, 100, 103, 99),
)
#: ITU T.81 Annex K.1: the standard chrominance quantisation table (quality 50), row major:
#: finer steps for the lowest frequencies (the upper left corner), 99 for all the others.
CHROMINANCE_TABLE = tuple(
    corner + (99,) * (8 - len(corner))
    for corner in ((17, 18, 24, 47), (18, 21, 26, 66), (24, 26, 56), (47, 66), (), (), (), ())
)


def quantisation_table(table: Sequence[Sequence[int]], quality: int) -> Tensor:
    """``table`` scaled to ``quality`` (1-100) as libjpeg's ``jpeg_quality_scaling`` does:
    ``5000 / q`` percent below 50, ``200 - 2 q`` from 50, rounded, clamped to ``[1, 255]``
    (quality 100: all ones)."""
    q = int(quality)
    if not 1 <= q <= 100:
        raise DataError(f"JPEG quality: expected 1-100, got {quality}")
    scale = 5000 // q if q < 50 else 200 - 2 * q
    t = torch.tensor(table, dtype=torch.float64)
    return ((t * scale + 50) // 100).clamp(1, 255).float()


def _dct_matrix(n: int = 8) -> Tensor:
    """The orthonormal DCT-II ``(n, n)``: for n = 8 its 2-D form is JPEG's FDCT exactly."""
    k = torch.arange(n, dtype=torch.float64).view(-1, 1)
    x = torch.arange(n, dtype=torch.float64).view(1, -1)
    m = torch.cos(math.pi * (2 * x + 1) * k / (2 * n)) * math.sqrt(2 / n)
    m[0] /= math.sqrt(2)
    return m.float()


_DCT = _dct_matrix()


def _srgb_decode_float(v: float) -> float:
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


#: Linear value of each 8-bit sRGB code, and the linear values where the rounded code steps
#: up: code ``k`` holds ``[decode((k - 0.5) / 255), decode((k + 0.5) / 255))``, computed in
#: Python floats.
_DECODE = torch.tensor([_srgb_decode_float(k / 255) for k in range(256)], dtype=torch.float32)
_STEPS = [_srgb_decode_float((k - 0.5) / 255) for k in range(1, 256)]
_LOW = torch.tensor([-math.inf, *_STEPS], dtype=torch.float32)
_HIGH = torch.tensor([*_STEPS, math.inf], dtype=torch.float32)


def _srgb_encode_8bit(x: Tensor) -> Tensor:
    """Linear values -> their rounded 8-bit sRGB codes (as floats), clipped to [0, 255].

    The curve's ``pow`` gives a code that may be one off at a step (torch's vectorised and
    scalar ``pow`` kernels differ in the last bit, and which elements take which depends on
    the batch: see :mod:`.procedural.noise`); exact comparisons with the steps then settle
    it, so a sample's codes are the same in any batch."""
    x = x.clamp(0, 1)
    v = torch.where(x <= 0.0031308, x * 12.92, x.clamp_min(0.0031308).pow(1 / 2.4) * 1.055 - 0.055)
    k = torch.round(v * 255).clamp(0, 255).long()
    low, high = _LOW.to(x.device), _HIGH.to(x.device)
    k = k + (x >= high[k]).long() - (x < low[k]).long()
    return k.to(x.dtype)


def _srgb_decode_8bit(v: Tensor) -> Tensor:
    """8-bit sRGB codes (integral floats in [0, 255]) -> linear values."""
    return _DECODE.to(v.device)[v.long()]


def _to_8bit(v: Tensor) -> Tensor:
    return torch.round(v).clamp(0, 255)


def _left(m: Tensor, x: Tensor) -> Tensor:
    """``m @ x`` for ``m`` ``(8, 8)`` and blocks ``x`` ``(..., 8, 8)``, as eight exactly rounded
    products and sums in a fixed order, so that a sample gives the same bits in any batch
    (a matmul's summation order is the BLAS kernel's choice)."""
    out = m[:, 0:1] * x[..., 0:1, :]
    for j in range(1, 8):
        out = out + m[:, j : j + 1] * x[..., j : j + 1, :]
    return out


def _right(x: Tensor, m: Tensor) -> Tensor:
    """``x @ m.T``, as :func:`_left`."""
    out = x[..., :, 0:1] * m[:, 0]
    for j in range(1, 8):
        out = out + x[..., :, j : j + 1] * m[:, j]
    return out


def _blocks_quantised(plane: Tensor, table: Tensor) -> Tensor:
    """8x8 DCT of ``plane`` ``(B, 1, H, W)`` (sides multiples of 8), each coefficient
    rounded to a multiple of its entry of ``table`` ``(B, 8, 8)``, and the inverse DCT."""
    b, _, h, w = plane.shape
    d = _DCT.to(plane.device)
    # (B, H/8, 8, W/8, 8) -> (B, H/8, W/8, 8, 8)
    blocks = plane.reshape(b, h // 8, 8, w // 8, 8).permute(0, 1, 3, 2, 4)
    coef = _right(_left(d, blocks), d)
    t = table.view(b, 1, 1, 8, 8)
    coef = torch.round(coef / t) * t
    out = _right(_left(d.T.contiguous(), coef), d.T.contiguous())
    return out.permute(0, 1, 3, 2, 4).reshape(b, 1, h, w)


def _halve(plane: Tensor) -> Tensor:
    """2x2 means of ``plane`` ``(B, 1, H, W)`` (odd sides: the edge repeated)."""
    h, w = plane.shape[-2:]
    p = F.pad(plane, (0, w % 2, 0, h % 2), mode="replicate")
    return ((p[..., ::2, ::2] + p[..., 1::2, ::2]) + (p[..., ::2, 1::2] + p[..., 1::2, 1::2])) * 0.25


def _double(plane: Tensor, h: int, w: int) -> Tensor:
    """``plane`` upsampled 2x by the triangle filter of libjpeg's "fancy" upsampling
    (each output 3/4 its nearest input, 1/4 the next; edges repeated), cropped to ``h x w``."""

    def along(p: Tensor, dim: int) -> Tensor:
        n = p.shape[dim]
        prev = torch.cat([p.narrow(dim, 0, 1), p.narrow(dim, 0, n - 1)], dim)
        nxt = torch.cat([p.narrow(dim, 1, n - 1), p.narrow(dim, n - 1, 1)], dim)
        even, odd = p * 0.75 + prev * 0.25, p * 0.75 + nxt * 0.25
        return torch.stack([even, odd], dim + 1).flatten(dim, dim + 1)

    return along(along(plane, 2), 3)[..., :h, :w]


def jpeg_roundtrip(
    photos: Tensor, quality: int | Sequence[int] | Tensor, *, subsampling: bool = True
) -> Tensor:
    """Linear photos ``(B, 3, H, W)`` (values outside ``[0, 1]`` are clipped, as a sensor's
    are) after a JPEG encode and decode at ``quality`` (1-100; one per photo, or one for
    all), linear again, float32 in ``[0, 1]``, on the input's device.

    ``subsampling``: chroma at half resolution in both directions (4:2:0, what phone cameras
    save); ``False`` keeps it whole (4:4:4).
    """
    if photos.dim() != 4 or photos.shape[1] != 3:
        raise DataError(f"jpeg_roundtrip: expected photos (B, 3, H, W), got {tuple(photos.shape)}")
    b, _, h, w = photos.shape
    qualities = [int(quality)] * b if isinstance(quality, (int, float)) else [int(q) for q in quality]
    if len(qualities) != b:
        raise DataError(f"jpeg_roundtrip: {len(qualities)} qualities for {b} photos")
    device = photos.device
    luma = torch.stack([quantisation_table(LUMINANCE_TABLE, q) for q in qualities]).to(device)
    chroma = torch.stack([quantisation_table(CHROMINANCE_TABLE, q) for q in qualities]).to(device)

    rgb = _srgb_encode_8bit(photos.float())
    r, g, bl = rgb[:, 0:1], rgb[:, 1:2], rgb[:, 2:3]
    # JFIF's full-range YCbCr, rounded to the encoder's 8-bit planes.
    y = _to_8bit(0.299 * r + 0.587 * g + 0.114 * bl)
    cb = _to_8bit(-0.168736 * r - 0.331264 * g + 0.5 * bl + 128)
    cr = _to_8bit(0.5 * r - 0.418688 * g - 0.081312 * bl + 128)

    def coded(plane: Tensor, table: Tensor, subsample: bool) -> Tensor:
        ph, pw = plane.shape[-2:]
        if subsample:
            plane = _to_8bit(_halve(plane))
        sh, sw = plane.shape[-2:]
        plane = F.pad(plane, (0, -sw % 8, 0, -sh % 8), mode="replicate")
        plane = _to_8bit(_blocks_quantised(plane - 128, table) + 128)[..., :sh, :sw]
        if subsample:
            plane = _to_8bit(_double(plane, ph, pw))
        return plane

    y = coded(y, luma, False)
    cb, cr = coded(cb, chroma, subsampling) - 128, coded(cr, chroma, subsampling) - 128
    rgb = torch.cat([y + 1.402 * cr, y - 0.344136 * cb - 0.714136 * cr, y + 1.772 * cb], dim=1)
    return _srgb_decode_8bit(_to_8bit(rgb))
