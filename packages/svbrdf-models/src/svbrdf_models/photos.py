"""Photos as they are shown: the EXIF orientation a camera records, applied to the pixels.

Used by the photo tool (:mod:`svbrdf_models.capture`) and by svbrdf-train's photo folders.
Pillow (svbrdf-render's ``io`` extra, or this package's ``photo`` extra) reads the tag; the
pixels are turned with torch alone.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

__all__ = ["EXIF_ORIENTATION", "exif_orientation", "file_orientation", "orient"]

#: The EXIF tag saying how to turn the stored pixels to show the photo upright (1-8).
EXIF_ORIENTATION = 0x0112


def exif_orientation(image) -> tuple[int, str | None]:
    """The EXIF orientation (1-8) of an open Pillow image, and a note for the user when it is applied,
    unreadable or invalid (both of the latter read as 1: the pixels as stored)."""
    try:
        orientation = int(image.getexif().get(EXIF_ORIENTATION, 1))
    except Exception:  # a damaged EXIF block: keep the pixels as stored
        return 1, "EXIF block unreadable: orientation not applied"
    if orientation not in range(1, 9):
        return 1, f"EXIF orientation {orientation} is not 1-8: ignored"
    return orientation, (f"EXIF orientation {orientation} applied" if orientation != 1 else None)


def file_orientation(path: str | Path) -> int:
    """The EXIF orientation of an image file (1 when it has none, or a damaged or invalid one)."""
    from PIL import Image

    with Image.open(path) as image:
        return exif_orientation(image)[0]


def orient(image: Tensor, orientation: int) -> Tensor:
    """Apply an EXIF orientation (1-8) to ``(C, H, W)``: what ``PIL.ImageOps.exif_transpose`` does
    to a Pillow image. The photo is turned after decoding, as a tensor, because Pillow holds no
    16-bit RGB image (16-bit PNGs are read at full precision by pypng); the tests hold the two
    equal for every orientation, 8- and 16-bit."""
    ops = {
        1: lambda t: t,
        2: lambda t: t.flip(-1),
        3: lambda t: t.flip(-1, -2),
        4: lambda t: t.flip(-2),
        5: lambda t: t.transpose(-1, -2),
        6: lambda t: torch.rot90(t, -1, (-2, -1)),
        7: lambda t: t.transpose(-1, -2).flip(-1, -2),
        8: lambda t: torch.rot90(t, 1, (-2, -1)),
    }
    return ops.get(int(orientation), ops[1])(image).contiguous()
