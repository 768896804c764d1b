"""Built-in example materials, generated analytically (nothing to download).

``example_material("tiles")`` and friends give something worth rendering on a fresh
install; the CLI accepts them as ``example:NAME``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .geometry import safe_normalize
from .maps import MAP_NAMES, SVBRDF

__all__ = ["EXAMPLES", "example_material"]


def _grid(size: int) -> tuple[Tensor, Tensor]:
    t = (torch.arange(size, dtype=torch.float64) + 0.5) / size
    y, x = torch.meshgrid(t, t, indexing="ij")
    return x, y


def _normals_from_height(height: Tensor, strength: float) -> Tensor:
    # Finite differences on a periodic grid; image rows grow downwards, y points up.
    size = height.shape[-1]
    dx = (torch.roll(height, -1, 1) - torch.roll(height, 1, 1)) * (size / 2)
    dy = (torch.roll(height, 1, 0) - torch.roll(height, -1, 0)) * (size / 2)
    n = torch.stack([-strength * dx, -strength * dy, torch.ones_like(height)])
    return safe_normalize(n, dim=0)


def _bumps(x: Tensor, y: Tensor, seed: int, octaves: int = 4) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    h = torch.zeros_like(x)
    for o in range(octaves):
        f = 2 ** (o + 2)
        ph = torch.rand(4, generator=g, dtype=torch.float64) * 2 * math.pi
        h += (torch.sin(2 * math.pi * f * x + ph[0]) * torch.sin(2 * math.pi * f * y + ph[1])
              + torch.sin(2 * math.pi * f * (x + y) + ph[2])) / (2 * f)
    return h


def _tiles(size: int) -> dict[str, Tensor]:
    x, y = _grid(size)
    n_tiles = 4
    u, v = (x * n_tiles) % 1, (y * n_tiles + 0.5 * (torch.floor(x * n_tiles) % 2)) % 1
    edge = torch.minimum(torch.minimum(u, 1 - u), torch.minimum(v, 1 - v))
    grout = (edge < 0.04).double()
    bevel = torch.clamp(edge / 0.08, 0, 1)
    height = 0.02 * bevel + 0.0007 * _bumps(x, y, 1)
    tile_id = torch.floor(x * n_tiles) * 7 + torch.floor(y * n_tiles + 0.5 * (torch.floor(x * n_tiles) % 2))
    tint = 0.85 + 0.15 * torch.sin(tile_id * 12.9898).abs()
    base = torch.tensor([0.55, 0.32, 0.22], dtype=torch.float64).view(3, 1, 1) * tint
    diffuse = base * (1 - grout) + 0.25 * grout
    rough = 0.25 + 0.6 * grout
    return {
        "normal": _normals_from_height(height, 8.0),
        "diffuse": diffuse,
        "roughness": rough.unsqueeze(0),
        "specular": (0.05 * (1 - grout) + 0.02 * grout).expand(3, -1, -1),
    }


def _metal(size: int) -> dict[str, Tensor]:
    x, y = _grid(size)
    g = torch.Generator().manual_seed(2)
    ph = torch.rand(64, generator=g, dtype=torch.float64) * 2 * math.pi
    streaks = sum(torch.sin(2 * math.pi * (k + 20) * y + ph[k]) / (k + 20) for k in range(64))
    height = 0.01 * streaks + 0.004 * _bumps(x, y, 3, octaves=2)
    rough = (0.3 + 2.0 * streaks).clamp(0.15, 0.5)
    return {
        "normal": _normals_from_height(height, 6.0),
        "diffuse": torch.full((3, size, size), 0.02, dtype=torch.float64),
        "roughness": rough.unsqueeze(0),
        "specular": torch.tensor([0.91, 0.78, 0.42], dtype=torch.float64).view(3, 1, 1).expand(3, size, size),
    }


def _leather(size: int) -> dict[str, Tensor]:
    x, y = _grid(size)
    g = torch.Generator().manual_seed(4)
    pts = torch.rand(64, 2, generator=g, dtype=torch.float64)
    px = torch.stack([x, y], dim=-1).reshape(-1, 1, 2)
    d = (px - pts).abs()
    d = torch.minimum(d, 1 - d).square().sum(-1).sqrt()
    two = d.topk(2, dim=1, largest=False).values
    cell = (two[:, 1] - two[:, 0]).reshape(size, size)
    height = 0.01 * torch.clamp(cell * 8, 0, 1) + 0.002 * _bumps(x, y, 5)
    crease = (cell < 0.02).double()
    return {
        "normal": _normals_from_height(height, 6.0),
        "diffuse": torch.tensor([0.18, 0.08, 0.04], dtype=torch.float64).view(3, 1, 1) * (1 - 0.5 * crease),
        "roughness": (0.45 + 0.3 * crease).unsqueeze(0),
        "specular": torch.full((3, size, size), 0.04, dtype=torch.float64),
    }


EXAMPLES = {
    "tiles": (_tiles, "terracotta tiles with rough grout"),
    "brushed-metal": (_metal, "gold-coloured brushed metal"),
    "leather": (_leather, "dark leather with creased cells"),
}


def example_material(name: str, size: int = 256, dtype: torch.dtype = torch.float32) -> SVBRDF:
    """A built-in material (batch of one); ``name`` is a key of :data:`EXAMPLES`."""
    if name not in EXAMPLES:
        raise KeyError(f"unknown example material {name!r}; choose from {', '.join(EXAMPLES)}")
    maps = EXAMPLES[name][0](size)
    return SVBRDF(
        *(maps[k].to(dtype).unsqueeze(0).contiguous() for k in MAP_NAMES)
    )
