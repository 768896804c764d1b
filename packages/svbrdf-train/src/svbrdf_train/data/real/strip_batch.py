"""Samples of material strips made on a training device, the whole batch at once.

:meth:`MaterialStrips.__getitems__ <.strips.MaterialStrips>` cuts, resizes and turns each
sample by itself on the CPU (the reference). :func:`strip_batch` makes the same samples in a
few batched ops on any device, for ``data.generate: device``: the bank is moved to the device
once (half precision, with a mip pyramid: each level the area mean of the one above), each
sample's window is read by ``grid_sample`` from the level whose size is nearest above the
window's share of the resolution (an affine grid per sample that holds the window, its turn
and its mirror), the normal vectors are turned and mirrored with the same matrices, the diffuse
factor and its ceiling are applied per sample, and the photos are rendered in one batched
render (:func:`..simulated_photo.photographs`). The draws (windows, turns, factors, photos) are the
CPU path's, from the same ``(seed, epoch, index)``; the maps differ from the CPU path's in how
a window is resampled (bilinear from the nearest mip level against an exact area filter): a
few thousandths of RMSE, tested.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import safe_normalize

from ..simulated_photo import draw_photo, photographs
from .strips import ALBEDO_CEILING

__all__ = ["strip_batch", "dihedral_matrix"]

_BANKS: dict = {}


def dihedral_matrix(k: int) -> Tensor:
    """``(2, 2)``: transform ``k`` of :func:`.des18.dihedral` on tangent vectors ``(x, y)``
    (``k % 4`` counter-clockwise quarter turns, then a left-right mirror for ``k >= 4``)."""
    turn = torch.tensor([[0.0, -1.0], [1.0, 0.0]])
    m = torch.linalg.matrix_power(turn, k % 4)
    return torch.diag(torch.tensor([-1.0, 1.0])) @ m if k >= 4 else m


def _pyramid(bank, device: torch.device) -> list[Tensor]:
    """The bank's maps on ``device`` as float16 ``(N, 10, S, S)`` and its area-mean mip levels
    down to 8 px, made once per bank and device."""
    key = (id(bank), str(device))
    hit = _BANKS.get(key)
    if hit is None or hit[0] is not bank:
        top = torch.stack([torch.from_numpy(m) for m in bank.maps]).to(device).half().div_(255)
        levels = [top]
        while levels[-1].shape[-1] >= 16:
            levels.append(F.avg_pool2d(levels[-1].float(), 2).half())
        hit = _BANKS[key] = (bank, levels)
    return hit[1]


def _grids(crops, tile: int, resolution: int, device) -> Tensor:
    """``(B, R, R, 2)`` sampling grids: output pixel -> its place in the sample's window, after
    the inverse of the sample's turn and mirror (normalised tile coordinates)."""
    theta = []
    for c in crops:
        inverse = dihedral_matrix(c.dihedral).T  # orthogonal: its inverse is its transpose
        # grid_sample's y grows downwards, tangent y upwards: conjugate by diag(1, -1)
        flip = torch.diag(torch.tensor([1.0, -1.0]))
        a = flip @ inverse @ flip * (c.side / tile)
        centre = torch.tensor([(2 * c.left + c.side) / tile - 1, (2 * c.top + c.side) / tile - 1])
        theta.append(torch.cat([a, centre[:, None]], dim=1))
    theta = torch.stack(theta).to(device)
    return F.affine_grid(theta, [len(crops), 1, resolution, resolution], align_corners=False)


def _sample(levels: list[Tensor], crops, grids: Tensor, resolution: int) -> Tensor:
    """``(B, 10, R, R)`` stored values of each window, read from its mip level."""
    out = grids.new_empty(len(crops), 10, resolution, resolution)
    by_level: dict[int, list[int]] = {}
    for b, c in enumerate(crops):
        level = int(math.floor(math.log2(max(c.side / resolution, 1.0)) + 1e-9))
        by_level.setdefault(min(level, len(levels) - 1), []).append(b)
    for level, rows in by_level.items():
        index = torch.tensor(rows, device=grids.device)
        source = levels[level][torch.tensor([crops[b].material for b in rows], device=grids.device)].float()
        out[index] = F.grid_sample(
            source, grids[index], mode="bilinear", padding_mode="border", align_corners=False
        )
    return out


def _windows(levels: list[Tensor], crops, r: int, device) -> Tensor:
    """``(B, 10, R, R)``: windows of the resolution's size read as they are (pixel centres:
    the CPU path's values), larger ones read at twice the resolution and averaged 2x2 (closer
    to the CPU path's area filter than one bilinear read)."""
    tile = levels[0].shape[-1]
    out = torch.empty(len(crops), 10, r, r, device=device)
    exact = [b for b, c in enumerate(crops) if c.side == r]
    resized = [b for b, c in enumerate(crops) if c.side != r]
    for rows, scale in ((exact, 1), (resized, 2)):
        if rows:
            part = [crops[b] for b in rows]
            read = _sample(levels, part, _grids(part, tile, scale * r, device), scale * r)
            out[torch.tensor(rows, device=device)] = F.avg_pool2d(read, scale) if scale > 1 else read
    return out


def strip_batch(data, indices: Sequence[int], device: torch.device | str) -> dict[str, Any]:
    """Samples ``indices`` of the :class:`~.strips.MaterialStrips` ``data`` made on ``device``:
    ``{"input": (B, 3, R, R), "maps": (B, 10, R, R), "name": [...]}`` (module doc)."""
    from svbrdf_render import SVBRDF

    device = torch.device(device)
    indices = [data._check(i) for i in indices]
    crops = [data.placement(i) for i in indices]
    r = data.resolution
    stored = _windows(_pyramid(data.bank, device), crops, r, device)
    turns = torch.stack([dihedral_matrix(c.dihedral) for c in crops]).to(device)
    n = stored[:, 0:3] * 2 - 1
    xy = torch.einsum("bij,bjhw->bihw", turns, n[:, 0:2])
    normal = safe_normalize(torch.cat([xy, n[:, 2:3]], dim=1), dim=1)
    diffuse = stored[:, 3:6]
    drawn = torch.tensor([c.albedo for c in crops], device=device)
    brightest = diffuse.flatten(1).amax(1)
    ceiling = torch.where(
        brightest > 0, ALBEDO_CEILING / brightest.clamp_min(1e-12), torch.ones_like(brightest)
    )
    factor = torch.where(drawn <= 1, drawn, torch.clamp(torch.minimum(drawn, ceiling), min=1.0))
    maps = SVBRDF(normal, diffuse * factor.view(-1, 1, 1, 1), stored[:, 6:7], stored[:, 7:10], validate=False)
    packed = maps.pack()
    seed = data._photo_seed()
    return {
        "input": photographs(packed, [draw_photo(seed, i, data.photo) for i in indices]),
        "maps": packed,
        "name": [data._name(i) for i in indices],
    }
