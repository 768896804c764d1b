"""Contact sheets: a batch of samples as one picture, to judge a data set at a glance.

One row per sample, one column per picture::

    label | input | normal | diffuse | roughness | specular

For viewing, not for measuring: the photo and the albedos are display-encoded with the
sRGB curve (they are stored linear), normals shown as ``(n + 1) / 2``, roughness as grey.
Text is drawn with Pillow's default font (Pillow comes with svbrdf-render's ``io`` extra).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from torch import Tensor

from svbrdf_models.capture.figures import image_grid
from svbrdf_models.errors import DataError
from svbrdf_render import MAP_NAMES, encode_normal
from svbrdf_render.formats.mapfiles import linear_to_srgb

__all__ = ["contact_sheet", "map_tiles", "COLUMNS"]

#: Column titles, left to right (after the label column).
COLUMNS = ("input", *MAP_NAMES)


def map_tiles(maps: Tensor) -> list[Tensor]:
    """The four maps of one packed sample ``(10, H, W)`` as display images ``(3, H, W)`` in [0, 1]:
    normal as ``(n + 1) / 2``, albedos sRGB-encoded, roughness grey."""
    m = maps.detach().float().cpu()
    return [
        encode_normal(m[0:3]).clamp(0, 1),
        linear_to_srgb(m[3:6]),
        m[6:7].clamp(0, 1).expand(3, -1, -1),
        linear_to_srgb(m[7:10]),
    ]


def _tiles(batch: dict[str, Any], input_encoding: str) -> list[list[Tensor]]:
    """Per sample, the five ``(3, H, W)`` display images in [0, 1]."""
    photos, maps = batch.get("input"), batch.get("maps")
    if photos is None or maps is None:
        raise DataError("contact sheet: expected a batch with 'input' and 'maps' (photos and ground truth)")
    if photos.dim() != 4 or maps.dim() != 4 or maps.shape[1] != 10 or photos.shape[1] != 3:
        raise DataError(
            f"contact sheet: expected input (B, 3, H, W) and maps (B, 10, H, W), got "
            f"{tuple(photos.shape)} and {tuple(maps.shape)}"
        )
    photos = photos.detach().float().cpu()
    shown = linear_to_srgb(photos) if input_encoding == "linear" else photos.clamp(0, 1)
    return [[shown[k], *map_tiles(maps[k])] for k in range(maps.shape[0])]


def contact_sheet(
    batch: dict[str, Any],
    labels: Sequence[str] | None = None,
    *,
    gap: int = 4,
    input_encoding: str = "linear",
) -> Tensor:
    """One picture of a batch: a header of column titles, then a row per sample.

    Args:
        batch: a collated batch (``input`` ``(B, 3, H, W)``, ``maps`` ``(B, 10, H, W)``,
            optionally ``name``), e.g. ``ProceduralMaterials.batch``.
        labels: one line of text per row (default: the batch's names).
        gap: pixels between tiles.
        input_encoding: ``"linear"`` (default) photos are sRGB-encoded for display,
            ``"srgb"`` ones shown as they are.

    Returns:
        ``(3, H', W')`` display-encoded values in [0, 1] (8-bit steps), ready for
        ``svbrdf_render.write_image``.
    """
    if input_encoding not in ("linear", "srgb"):
        raise DataError(f"contact sheet: input_encoding must be 'linear' or 'srgb', got {input_encoding!r}")
    rows = _tiles(batch, input_encoding)
    if labels is None:
        names = batch.get("name")
        labels = [str(s) for s in names] if names is not None else [str(k) for k in range(len(rows))]
    return image_grid(rows, COLUMNS, labels, gap=gap)
