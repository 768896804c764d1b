"""What a procedural family is, the table of families, and the batching its ``fields`` relies on.

A family module defines ``draw(d)`` and ``fields(p, x, y)`` and ends by registering them with
its place in the drawing order and its weight (:mod:`svbrdf_train.data.procedural.families` says how such
a module looks): ``register(Family(name, description, draw, fields, order=..., weight=...))``.
The table lists the families by their declared ``order`` whatever order they register in, so
the drawing order is written in the family modules alone, and :func:`family_fingerprint` names
the table for the generator's version.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor

from svbrdf_models.errors import DataError

from ..noise import Draw

__all__ = [
    "Fields",
    "Family",
    "FAMILY_TABLE",
    "family_fingerprint",
    "register",
    "stack_choices",
    "pixel_grid",
]


class Fields(NamedTuple):
    """Maps of a batch before normals (see :mod:`svbrdf_train.data.procedural.families`)."""

    height: Tensor  # (B, 1, H, W), patch units
    diffuse: Tensor  # (B, 3, H, W), linear
    roughness: Tensor  # (B, 1, H, W)
    specular: Tensor  # (B, 3, H, W), linear
    parts: dict[str, Tensor]  # name -> (B, 1, H, W) mask in [0, 1]


@dataclass(frozen=True)
class Family:
    """One family of materials: its description, its two functions, and how it is drawn.

    ``order``: its place in the drawing order, an integer; families are listed and drawn from
    in increasing order (a sample picks its family by position in that list, so the order is
    part of the generator's output), and no two families declare the same. ``weight``: how
    often it is drawn, relative to the other families' weights (a finite number > 0).
    """

    name: str
    description: str
    draw: Callable[[Draw], dict[str, Any]]
    fields: Callable[[dict[str, Tensor], Tensor, Tensor], Fields]
    _: KW_ONLY
    order: int
    weight: float

    def __post_init__(self) -> None:
        if isinstance(self.order, bool) or not isinstance(self.order, int):
            raise DataError(f"material family {self.name!r}: order must be an integer, got {self.order!r}")
        weight = self.weight
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight):
            raise DataError(f"material family {self.name!r}: weight must be a finite number, got {weight!r}")
        if weight <= 0:
            raise DataError(f"material family {self.name!r}: weight must be > 0, got {weight!r}")


#: Every registered family by name, in their declared ``order`` (the drawing order).
FAMILY_TABLE: dict[str, Family] = {}


def register(family: Family) -> Family:
    """Add ``family`` to :data:`FAMILY_TABLE` at its declared place in the drawing order; a name
    and an order register once."""
    if family.name in FAMILY_TABLE:
        raise DataError(f"material family {family.name!r} is registered twice; give the new one another name")
    for other in FAMILY_TABLE.values():
        if other.order == family.order:
            raise DataError(
                f"material families {other.name!r} and {family.name!r} both declare order {family.order}; "
                "give the new one another place in the drawing order"
            )
    ordered = sorted([*FAMILY_TABLE.values(), family], key=lambda f: f.order)
    FAMILY_TABLE.clear()
    FAMILY_TABLE.update((f.name, f) for f in ordered)
    return family


def family_fingerprint(table: dict[str, Family] | None = None) -> str:
    """A short hash of what the generator draws its families by: their names and weights in the
    drawing order (of ``table``, default :data:`FAMILY_TABLE`). Another family, another
    weight or another order gives another fingerprint; the order's numbers alone do not."""
    table = FAMILY_TABLE if table is None else table
    text = repr([(name, float(family.weight)) for name, family in table.items()])
    return hashlib.sha256(text.encode()).hexdigest()[:8]


def stack_choices(
    choices: list[dict[str, Any]], device: torch.device | str | None = None
) -> dict[str, Tensor]:
    """Per-material choices -> batched tensors: floats ``(B, 1, 1, 1)``, RGB ``(B, 3, 1, 1)``,
    tensors ``(B, ...)``; on ``device`` when given (stacked on the CPU, then copied over
    together: one transfer of every float32 table instead of one per key)."""
    out = {}
    for key in choices[0]:
        values = [c[key] for c in choices]
        if isinstance(values[0], Tensor):
            out[key] = torch.stack(values)
        else:
            t = torch.tensor(values, dtype=torch.float32)
            out[key] = t.view(len(values), -1, 1, 1)
    if device is None or torch.device(device).type == "cpu":
        return out
    return _to_device(out, torch.device(device))


def _to_device(tensors: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    """``tensors`` on ``device``: the float32 ones packed into one buffer and copied at once
    (a copy per tensor costs a transfer's latency each), the others one by one."""
    floats = [k for k, t in tensors.items() if t.dtype == torch.float32]
    out = {k: t.to(device) for k, t in tensors.items() if t.dtype != torch.float32}
    if floats:
        flat = torch.cat([tensors[k].reshape(-1) for k in floats]).to(device)
        sizes = [tensors[k].numel() for k in floats]
        for k, part in zip(floats, torch.split(flat, sizes), strict=True):
            out[k] = part.view(tensors[k].shape)
    return {k: out[k] for k in tensors}


def pixel_grid(
    resolution: int, margin: int = 0, device: torch.device | str | None = None
) -> tuple[Tensor, Tensor]:
    """Pixel centres in patch units, with ``margin`` extra pixels on every side.

    ``x`` ``(1, 1, 1, R + 2m)`` left to right, ``y`` ``(1, 1, R + 2m, 1)`` top (``+1``) to
    bottom, as :func:`svbrdf_render.surface_positions` places them; made on ``device``
    (default the CPU), so that the fields computed from them are computed there.
    """
    n = resolution + 2 * margin
    t = ((torch.arange(n, dtype=torch.float32, device=device) - margin) * 2 + 1) / resolution - 1
    return t.view(1, 1, 1, -1), (-t).view(1, 1, -1, 1)
