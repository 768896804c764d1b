"""The printed frame's reference strip: a shot's flash read off the paper beside the window.

The strip (:attr:`~svbrdf_models.capture.frame.FrameLayout.strip_rect`) is unprinted paper
under the bottom markers, outside the window that is the patch ``[-1, 1]^2``. Each shot's
:func:`~svbrdf_models.capture.framephoto.rectify` samples it and says where each sample lies
(half-widths of the window, z = 0). :func:`card_shading` renders a matte card at those points
through the renderer's own image formation (the card's maps of
:func:`svbrdf_render.refinement.fit.card_maps`, the shot's camera and its flash apart from it,
cosine and fall-off) at unit intensity: the renderer draws the patch, so the scene is shifted
and scaled until the patch covers the strip (lengths divided by ``s``, the intensity by
``s^2``: the same light reaches each point), and the rendering is read at the strip's points.
:func:`read_strip` then takes the flash's intensity and colour as the median of photo over
rendering (:func:`svbrdf_render.refinement.fit.reference_flash`).

With the paper's albedo stated (``--strip-albedo A``; plain printer paper is about 0.8) that
is each shot's flash, absolutely; without it the readings of two shots still give their
exposures' ratio (the albedo cancels). A strip more than half clipped or too dark to read
(the thresholds of a ``--reference`` region, :mod:`svbrdf_models.capture.reference`) says
nothing: :func:`check_strip` refuses it in one line naming the shot.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import Camera, PointLight, Scene, render

from ..errors import DataError
from .reference import _CLIPPED_SHARE, MIN_LEVEL

__all__ = ["NOMINAL_ALBEDO", "StripReading", "card_shading", "check_strip", "read_strip"]

#: The albedo the strip is read with when none is stated: its readings then say only the
#: shots' exposures relative to each other (about that of plain printer paper).
NOMINAL_ALBEDO = 0.8
#: The side of the card's rendering the strip's points are read from (bilinear): the card's
#: shading varies smoothly, a few pixels per centimetre are plenty.
_CARD_SIDE = 256


def card_shading(xy: Tensor, camera: Tensor, light: Tensor, albedo: float) -> Tensor:
    """``(3, h, w)``: a flat matte card of ``albedo`` at the plane's points ``xy`` ``(2, h, w)``
    (half-widths of the window, z = 0) as the renderer shows it with the camera at ``camera``
    and a light of unit intensity at ``light`` (both ``(3,)``, half-widths)."""
    from svbrdf_render.refinement.fit import card_maps

    xy = xy.float()
    lo, hi = xy.flatten(1).amin(1), xy.flatten(1).amax(1)
    centre = (lo + hi) / 2
    s = float((hi - lo).amax()) / 2 * 1.05 + 1e-3  # the patch's half side, a margin around the points
    shift = torch.cat([centre, centre.new_zeros(1)])

    def moved(p: Tensor) -> Tensor:
        return (p.float().reshape(3) - shift) / s

    scene = Scene(Camera(moved(camera)), (PointLight(moved(light), 1.0 / s**2),))
    card = render(card_maps(albedo, (_CARD_SIDE, _CARD_SIDE)), scene)  # (1, 3, S, S), row 0 at y = +1
    grid = torch.stack([(xy[0] - centre[0]) / s, -(xy[1] - centre[1]) / s], dim=-1)[None]
    return F.grid_sample(card, grid, mode="bilinear", padding_mode="border", align_corners=False)[0]


@dataclass(frozen=True)
class StripReading:
    """What a shot's strip says (:func:`read_strip`).

    Attributes:
        intensity: the flash's intensity for a card of ``albedo`` (half-widths; luminance).
        color: ``(3,)`` the flash's colour as the photo shows it (per-channel gain over
            ``intensity``).
        albedo: the albedo it was read with.
        clipped, dark: shares of the strip's samples clipped (at or above 0.98) and too dark.
        level: the strip's mean luminance in the photo (linear).
        pixels: samples read.
    """

    intensity: float
    color: Tensor
    albedo: float
    clipped: float
    dark: float
    level: float
    pixels: int

    @property
    def readable(self) -> bool:
        """Whether the strip says anything: not more than half clipped or dark, bright enough,
        with a few samples read."""
        return (self.clipped <= _CLIPPED_SHARE and self.dark <= _CLIPPED_SHARE and self.level >= MIN_LEVEL
                and self.pixels >= 4)  # fmt: skip

    def record(self) -> dict:
        """material.json's ``strip`` of a shot."""
        return {"albedo": self.albedo, "intensity": round(self.intensity, 6),
                "color": [round(float(c), 4) for c in self.color], "level": round(self.level, 6),
                "clipped": round(self.clipped, 4), "dark": round(self.dark, 4), "samples": self.pixels,
                "readable": self.readable}  # fmt: skip


def read_strip(strip: Tensor, xy: Tensor, camera: Tensor, flash: Tensor, albedo: float) -> StripReading:
    """The flash of a shot read off its strip's samples ``strip`` ``(3, h, w)`` (linear) at the
    points ``xy`` ``(2, h, w)``, seen from ``camera`` with the flash at ``flash`` (half-widths),
    the paper taken to be of ``albedo``."""
    from svbrdf_render.refinement.fit import reference_flash

    unit = card_shading(xy, camera, flash, albedo)[None]
    photo = strip.float()[None]
    mask = torch.ones(1, 1, *photo.shape[-2:], dtype=torch.bool)
    measured = reference_flash(photo, mask, albedo, None, unit=unit)
    return StripReading(float(measured.intensity[0]), measured.color[0], float(albedo),
                        float(measured.clipped[0]), float(measured.dark[0]), float(measured.level[0]),
                        int(measured.pixels[0]))  # fmt: skip


def check_strip(reading: StripReading, name: str) -> None:
    """Refuse (one line naming the shot) a strip that cannot say the flash of a stated albedo."""
    head = f"{name}: --strip-albedo {reading.albedo:g}: the frame's reference strip"
    if reading.clipped > _CLIPPED_SHARE:
        raise DataError(
            f"{head} is {reading.clipped:.0%} clipped (white) in the photo, so the flash cannot be read "
            "from it; lower the exposure (lock it on the frame), or leave out --strip-albedo"
        )
    if reading.dark > _CLIPPED_SHARE or reading.level < MIN_LEVEL or reading.pixels < 4:
        raise DataError(
            f"{head} is too dark to read (mean {reading.level:.4f} of 1, linear); light it with the "
            "flash, raise the exposure, keep it uncovered, or leave out --strip-albedo"
        )
