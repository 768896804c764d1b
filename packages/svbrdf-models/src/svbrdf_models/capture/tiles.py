"""Maps larger than the model's input, from overlapping tiles blended without seams, and what a
tiled capture costs in memory.

A tiled capture (``--tiles``) holds about :data:`TILED_BYTES_PER_PIXEL` bytes per pixel of its
maps: :func:`check_tiled_memory` refuses, before any work, a size this machine's available
memory cannot hold.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from svbrdf_render import SVBRDF, safe_normalize
from svbrdf_render.plumbing import machine

from ..errors import DataError

__all__ = [
    "TILED_BYTES_PER_PIXEL",
    "TILED_FIXED_BYTES",
    "check_tiled_memory",
    "tile_count",
    "tile_predict",
    "tiled_capture_bytes",
]

#: Peak memory of a tiled capture per pixel of its maps: the photo at that size, the blended maps
#: and their weights, the flash fit's re-renderings and gradients, the figures and the files'
#: buffers (about 70 float32 values). Measured as capture_one's peak resident memory with
#: --tiles: 4.1 GiB above the program at 4096 px (263 bytes per pixel), 240-270 bytes per pixel
#: added from 512 to 4096 px; so 8192 px maps need about 18 GiB.
TILED_BYTES_PER_PIXEL = 280
#: ... and beyond the per-pixel part, whatever the size (measured: about 270 MiB at 512 px).
TILED_FIXED_BYTES = 320 * 2**20


def _positions(length: int, tile: int, stride: int) -> list[int]:
    if length <= tile:
        return [0]
    n = math.ceil((length - tile) / stride) + 1
    return sorted({round(i * (length - tile) / (n - 1)) for i in range(n)})


def _window(tile: int) -> Tensor:
    """Raised cosine (Hann) that never reaches 0: ``sin^2(pi (i + 1/2) / tile)``; with 50% overlap
    neighbouring windows sum to exactly 1."""
    i = torch.arange(tile, dtype=torch.float64)
    return torch.sin(math.pi * (i + 0.5) / tile).square().float()


def tile_predict(
    predict_fn: Callable[[Tensor], SVBRDF], photo: Tensor, tile: int, overlap: float = 0.5, *, batch: int = 8
) -> SVBRDF:
    """Maps of a photo larger than the model's input, from overlapping tiles blended without seams.

    Args:
        predict_fn: ``(N, 3, tile, tile)`` linear photos -> SVBRDF of N materials of that size.
        photo: ``(3, H, W)`` linear, ``H, W >= tile``.
        tile: side of a tile (the model's resolution).
        overlap: share of a tile its neighbour covers (0.5: half).
        batch: tiles per call of ``predict_fn``.

    Tiles start at evenly spread positions that end flush with the borders; each tile's maps are
    weighted by a separable raised-cosine window, summed, and divided by the sum of the weights,
    so the result is a smooth partition of unity. Normals are re-normalised after blending;
    the other maps are clamped to [0, 1]. Returns a batch of one at ``H x W``.
    """
    _, h, w = photo.shape
    if h < tile or w < tile:
        raise DataError(f"tile_predict: the photo is {w}x{h}, smaller than a tile ({tile})")
    if not 0 <= overlap < 1:
        raise DataError(f"tile_predict: overlap must be in [0, 1), got {overlap}")
    stride = max(1, round(tile * (1 - overlap)))
    corners = [(y, x) for y in _positions(h, tile, stride) for x in _positions(w, tile, stride)]
    win = _window(tile)
    weight = (win[:, None] * win[None, :])[None]  # (1, tile, tile)
    acc = torch.zeros(10, h, w)
    total = torch.zeros(1, h, w)
    for start in range(0, len(corners), batch):
        chunk = corners[start : start + batch]
        x = torch.stack([photo[:, y : y + tile, x : x + tile] for y, x in chunk])
        maps = predict_fn(x)
        packed = torch.cat([maps.normal, maps.diffuse, maps.roughness, maps.specular], 1).float().cpu()
        for k, (y, x) in enumerate(chunk):
            acc[:, y : y + tile, x : x + tile] += packed[k] * weight
            total[:, y : y + tile, x : x + tile] += weight
    out = (acc / total)[None]
    return SVBRDF(
        safe_normalize(out[:, 0:3], dim=1),
        out[:, 3:6].clamp(0, 1),
        out[:, 6:7].clamp(0, 1),
        out[:, 7:10].clamp(0, 1),
        validate=False,
    )


def tile_count(size: int, tile: int, overlap: float = 0.5) -> int:
    """How many tiles :func:`tile_predict` runs on a ``size x size`` photo."""
    return len(_positions(size, tile, max(1, round(tile * (1 - overlap))))) ** 2


def tiled_capture_bytes(size: int) -> int:
    """About how much memory a tiled capture of ``size x size`` maps takes at its peak, beyond
    the program and the model (see :data:`TILED_BYTES_PER_PIXEL`)."""
    return TILED_BYTES_PER_PIXEL * size * size + TILED_FIXED_BYTES


def check_tiled_memory(size: int, what: str) -> None:
    """Refuse (:class:`DataError`, one line starting with ``what``) a tiled capture of ``size x
    size`` maps that needs more memory than :func:`svbrdf_render.plumbing.available_memory` says
    there is; a tiled capture past it would be killed by the system, or swap for hours, after
    minutes of work."""
    need, have = tiled_capture_bytes(size), machine.available_memory()
    if have is None or need <= have:
        return
    largest = math.isqrt(max(0, have - TILED_FIXED_BYTES) // TILED_BYTES_PER_PIXEL)
    raise DataError(
        f"{what}: a tiled capture of {size}x{size} maps needs about {need / 2**30:.1f} GiB of memory, "
        f"but {have / 2**30:.1f} GiB are available; give a --map-size of at most {largest} px, or "
        "free memory"
    )
