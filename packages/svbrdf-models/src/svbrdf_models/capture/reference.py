"""A region of known albedo in the photo (a grey card) pins the level of the diffuse albedo.

One photo cannot separate the albedo from the flash's power: every albedo twice as bright
under a flash half as strong gives the same photo. The network's maps carry a guess of the
level learnt from its training data. A user who puts a card of known albedo in the picture
(``svbrdf-models predict --reference X,Y,W,H:ALBEDO``; an 18% grey card is 0.18, a white
sheet of printer paper about 0.8) gives the capture the level itself: the network's diffuse
map is scaled so that its mean over the card is ``ALBEDO``, and the refinement, which starts
from and is pulled toward those maps, finds the flash that matches (the card must be in the
square that is captured, lit by the flash like the material, and not clipped).

    ref = Reference.parse("120,80,60,60:0.18")        # x, y, width, height in photo pixels
    maps, record = pin_albedo(maps, square, ref, square_box(path, crop), "shot.jpg")
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from svbrdf_render import SVBRDF

from ..errors import DataError

__all__ = ["Reference", "pin_albedo"]

#: Photo values at or above this are clipped; a region more than half clipped says too little
#: of its level to pin the albedo by.
_SATURATED, _CLIPPED_SHARE = 0.98, 0.5
#: Luminance weights (Rec. 709) of the region's mean albedo.
_LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class Reference:
    """A region of the photo (pixels of the photo as displayed) whose albedo is known."""

    x: int
    y: int
    width: int
    height: int
    albedo: float

    @classmethod
    def parse(cls, text: str) -> Reference:
        """``X,Y,W,H:ALBEDO``; a :class:`DataError` naming what is wrong otherwise."""
        where = f"--reference {text!r}"
        box, sep, value = str(text).partition(":")
        try:
            x, y, w, h = (int(v) for v in box.split(","))
            albedo = float(value)
        except ValueError:
            raise DataError(
                f"{where}: expected X,Y,W,H:ALBEDO (pixels, then the albedo), e.g. 120,80,60,60:0.18"
            ) from None
        if not sep or w <= 0 or h <= 0:
            raise DataError(f"{where}: the region has no area; give a width and a height of at least 1 px")
        if x < 0 or y < 0:
            raise DataError(f"{where}: X and Y must be >= 0 (pixels from the top left of the photo)")
        if not 0 < albedo <= 1:
            raise DataError(f"{where}: the albedo must be in (0, 1] (an 18% grey card is 0.18), got {value}")
        return cls(x, y, w, h, albedo)

    def describe(self) -> str:
        return f"{self.x},{self.y},{self.width},{self.height}:{self.albedo:g}"


def _window(
    ref: Reference, box: tuple[int, int, int, int, int], size: int, where: str
) -> tuple[int, int, int, int]:
    """The region in pixels of maps of ``size`` made of the square ``box`` = (x0, y0, side, W, H)."""
    x0, y0, side, width, height = box
    head = f"{where}: --reference {ref.describe()}"
    if ref.x + ref.width > width or ref.y + ref.height > height:
        raise DataError(
            f"{head} lies outside the {width}x{height} photo (as displayed); give a region inside it"
        )
    if ref.x < x0 or ref.y < y0 or ref.x + ref.width > x0 + side or ref.y + ref.height > y0 + side:
        raise DataError(
            f"{head} is not inside the square captured ({x0},{y0} to {x0 + side},{y0 + side}); "
            "move it, or pick the square with --crop"
        )
    scale = size / side
    top, left = int((ref.y - y0) * scale), int((ref.x - x0) * scale)
    bottom = max(top + 1, round((ref.y + ref.height - y0) * scale))
    right = max(left + 1, round((ref.x + ref.width - x0) * scale))
    return top, left, min(bottom, size), min(right, size)


def pin_albedo(
    maps: SVBRDF, square: Tensor, ref: Reference, box: tuple[int, int, int, int, int], where: str
) -> tuple[SVBRDF, dict]:
    """``maps`` (one material) with the diffuse albedo scaled so that its mean luminance over the
    reference region is ``ref.albedo`` (clamped to [0, 1]), and the record of it.

    ``square`` is the photo's square ``(3, S, S)`` (linear), ``box`` where that square lies in
    the photo (:func:`svbrdf_models.capture.photos.square_box`), ``where`` the photo's name for errors.

    Raises:
        DataError: a region outside the photo or the square, or more than half clipped in the
            photo (its level cannot be read), or where the maps' diffuse is black.
    """
    t, l, b, r = _window(ref, box, square.shape[-1], where)
    clipped = float((square[:, t:b, l:r].amax(dim=0) >= _SATURATED).float().mean())
    if clipped > _CLIPPED_SHARE:
        raise DataError(
            f"{where}: --reference {ref.describe()}: {clipped:.0%} of the region is clipped (white) in the "
            "photo, so its level cannot be read; lower the exposure, or give a region that is not blown out"
        )
    tm, lm, bm, rm = _window(ref, box, maps.size[0], where)
    luma = torch.tensor(_LUMA, dtype=maps.diffuse.dtype).view(1, 3, 1, 1)
    level = float((maps.diffuse[:, :, tm:bm, lm:rm] * luma).sum(dim=1).mean())
    if level <= 1e-4:
        raise DataError(
            f"{where}: --reference {ref.describe()}: the maps' diffuse is black there; nothing to scale"
        )
    scale = ref.albedo / level
    pinned = SVBRDF(
        maps.normal, (maps.diffuse * scale).clamp(0, 1), maps.roughness, maps.specular, validate=False
    )
    return pinned, {"region": [ref.x, ref.y, ref.width, ref.height], "albedo": ref.albedo, "scale": scale}
