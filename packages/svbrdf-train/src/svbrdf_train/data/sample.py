"""The one sample layout every data source returns, so DataLoader's default collate works.

A sample is a dict:

=========  ==============  ============================================================
key        shape           meaning
=========  ==============  ============================================================
input      (3, H, W)       the photo, linear radiance, float32 (clipped photos lie in [0, 1])
maps       (10, H, W)      the four maps packed as ``SVBRDF.pack`` does (absent without ground truth)
name       str             where the sample came from (file name, or ``procedural:<seed>:<index>``)
=========  ==============  ============================================================

A collated batch has the same keys with a leading batch dimension; :func:`batch_svbrdf` turns
its ``maps`` back into an :class:`~svbrdf_render.SVBRDF`.
"""

from __future__ import annotations

from typing import Any

from svbrdf_render import SVBRDF

__all__ = ["batch_svbrdf"]


def batch_svbrdf(batch: dict[str, Any], *, validate: bool = False) -> SVBRDF:
    """The ground-truth maps of a collated batch, ``maps`` ``(B, 10, H, W)`` -> SVBRDF."""
    return SVBRDF.unpack(batch["maps"], validate=validate)
