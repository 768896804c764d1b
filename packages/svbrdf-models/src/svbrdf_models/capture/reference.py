"""A region of known albedo in the photo (a grey card) measures the flash, and with it the
level of every albedo.

One photo cannot separate the albedo from the flash's power: every albedo twice as bright
under a flash half as strong gives the same photo. Without help, the level is the network's
guess, learnt from its training data. A user who puts a matte card of known albedo in the
captured square (``svbrdf-models predict --reference X,Y,W,H:ALBEDO``; an 18% grey card is
0.18, white printer paper about 0.8) lets the capture *measure* the flash instead:
:func:`pin_flash` renders the card through the renderer's own image formation at unit
intensity (each pixel's place in the field of view, its distance, cosine and fall-off, a matte
card's small specular: :func:`svbrdf_render.refinement.fit.reference_flash`) and reads the
flash's intensity and colour off the photo's pixels over the card. The refinement then runs
under the measured flash, which sets the albedos' level, with the card's pixels held at the
card's maps (they are not the material); the network is shown the photo with the card filled
in from the material around it (:func:`fill_card`), and the highlight finder ignores the
card, which is often brighter than the material. Without refinement (``--refine 0``) the
maps are the network's: the card is recorded, and judged, but sets nothing.

It is never the network's diffuse over the card that sets the level: the network sees a
card at the edge of a flash photo darker than it is (it does not follow the fall-off there),
and scaling every albedo to make that patch 0.18 made them 2.5-3 times too bright.

    ref = Reference.parse("120,80,60,60:0.18")        # x, y, width, height in photo pixels
    pinned = pin_flash(square, maps, ref, square_box(path, crop), "shot.jpg")
    pinned.scene, pinned.record                        # the flash measured; material.json's section
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from svbrdf_render import SVBRDF, Scene

from ..errors import DataError

__all__ = [
    "CARD_CLIPPED_SHARE",
    "CARD_MIN_LEVEL",
    "MIN_ALBEDO",
    "PinnedFlash",
    "Reference",
    "fill_card",
    "pin_flash",
    "reference_mask",
    "with_card",
]

#: A printed frame's reference strip (:mod:`svbrdf_models.capture.strip`) more than this share
#: clipped (or too dark) in the photo says too little to read the flash from; a card is held to
#: :data:`CARD_CLIPPED_SHARE`.
_CLIPPED_SHARE = 0.5
#: The strip's mean in the photo (linear) below which it is too dark to read (about 20 of 255
#: in sRGB): noise and the JPEG's quantisation would set the flash; a card: :data:`CARD_MIN_LEVEL`.
MIN_LEVEL = 0.007
#: The albedo a reference may state at least: the darkest matte materials (black velvet,
#: carbon black paint) reflect about 1-2%; below, it is no reference.
MIN_ALBEDO = 0.01
#: A card is read from its pixels that are neither clipped nor black, so each of those it
#: loses biases the reading (clipped ones: the flash read too weak); more than this share of
#: the region at white, or at black, and it is refused (issue 47: a region on the photo's
#: highlight passed; on the 21 real-dev photos one there is 0-47% clipped, under the half that
#: :data:`_CLIPPED_SHARE` allows). Good cards in rendered photos (an 18% card in any corner,
#: exposures 0.35-3) have none clipped.
CARD_CLIPPED_SHARE = 0.05
#: The card's mean in the photo (linear) below which it is too dark to read: about 30 of 255
#: in sRGB, where one 8-bit step is 6% of the value and the sensor's noise, the JPEG's
#: quantisation and any light besides the flash set the reading.
CARD_MIN_LEVEL = 0.012
#: The material's albedo level implied by the card may differ from the network's guess by at
#: most this factor either way: good 18% cards in rendered photos of the 30 unseen-dev and
#: des18-dev materials at exposures 0.35-3 give 0.37-3.6, and one in a photo so dim that the
#: card is at :data:`CARD_MIN_LEVEL` 7.5 (the network does not follow the exposure all the
#: way). Beyond, the region is not a card of that albedo (a region on the material or the
#: highlight, a wrong albedo), and the capture says so instead of refining every albedo to 15
#: times too bright (issue 47: a region on the highlight gave 18.2, and passed the 20 allowed
#: before). Nor may the network's diffuse at that level be more than :data:`MAX_WHITE` white
#: (no real material reflects all the light; good cards: none), or its median darker than
#: :data:`MIN_MATERIAL` (no real non-metal is) over the pixels the network takes for a non-metal
#: (specular luminance under :data:`METAL_SPECULAR`); a metal's diffuse is black, its colour in
#: its specular, so a material the network takes for metal over half its pixels or more is not
#: held to it (a polished metal floor of des18-dev, network diffuse 0.002, was refused); nor is a
#: card that darkens the network's level by less than :data:`AGREES` (it confirms what the
#: network saw: a dark marble and metal strip, network median 0.0034, read 1.2 times darker).
MAX_LEVEL_RATIO, MAX_WHITE, MIN_MATERIAL = 15.0, 0.10, 0.003
METAL_SPECULAR = 0.25
AGREES = 2.0


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
        if not MIN_ALBEDO <= albedo <= 1:
            raise DataError(
                f"{where}: the albedo must be in [{MIN_ALBEDO}, 1] (an 18% grey card is 0.18, white paper "
                f"about 0.8), got {value}"
            )
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


def reference_mask(ref: Reference, box: tuple[int, int, int, int, int], size: int, where: str) -> Tensor:
    """``(1, 1, size, size)``: true over the region in maps of ``size`` made of the square ``box``."""
    t, l, b, r = _window(ref, box, size, where)
    mask = torch.zeros(1, 1, size, size, dtype=torch.bool)
    mask[..., t:b, l:r] = True
    return mask


def fill_card(photo: Tensor, mask: Tensor) -> Tensor:
    """``photo`` ``(3, H, W)`` with the pixels where ``mask`` ``(1, 1, H, W)`` is true filled
    from the material around them (push-pull: averages of the known pixels on coarser and
    coarser grids, brought back up smoothly): what the network sees. It never saw a grey card
    in training, and one in the photo changed its maps of the material around it (on unseen-dev
    a card in a corner made the network's diffuse 3x worse on the facade); the card itself is
    read from the photo as it is."""
    import torch.nn.functional as F

    def fill(x: Tensor, known: Tensor) -> Tensor:
        h, w = x.shape[-2:]
        if bool(known.all()) or min(h, w) < 2:
            return x
        sx = F.avg_pool2d(x * known, 2, ceil_mode=True)
        sk = F.avg_pool2d(known, 2, ceil_mode=True)
        coarse = fill(sx / sk.clamp_min(1e-6), (sk > 0).to(x.dtype))
        up = F.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)
        return torch.where(known > 0, x, up)

    m = mask.to(photo.device)
    if tuple(m.shape[-2:]) != tuple(photo.shape[-2:]):
        m = F.interpolate(m.float(), size=tuple(photo.shape[-2:]), mode="nearest") > 0.5
    known = (~m.to(torch.bool)).to(photo.dtype)
    if not bool(known.any()):
        return photo
    return fill(photo[None], known)[0]


def with_card(maps: SVBRDF, mask: Tensor, card: SVBRDF) -> SVBRDF:
    """``maps`` with ``card``'s maps where ``mask`` (brought to the maps' size) is true."""
    import torch.nn.functional as F

    h, w = maps.size
    if tuple(mask.shape[-2:]) != (h, w):
        mask = F.interpolate(mask.float(), size=(h, w), mode="nearest") > 0.5
    card = card.resize(h, w) if tuple(card.size) != (h, w) else card
    return SVBRDF(
        *(torch.where(mask.to(t.device), getattr(card, n).to(t).expand_as(t), t) for n, t in maps.maps().items()),
        validate=False,
    )


@dataclass(frozen=True)
class PinnedFlash:
    """What a reference measured (:func:`pin_flash`).

    Attributes:
        scene: camera and flash at their place, with the measured intensity and colour.
        mask: ``(1, 1, S, S)`` true over the card, in the square's pixels.
        card: the card's maps (:func:`svbrdf_render.refinement.fit.card_maps`), ``S`` px.
        record: material.json's ``reference`` section.
    """

    scene: Scene
    mask: Tensor
    card: SVBRDF
    record: dict

    def start(self, network: SVBRDF) -> SVBRDF:
        """The network's maps with the card's maps over the card: the refinement's start."""
        return with_card(network, self.mask, self.card)


def pin_flash(
    square: Tensor,
    network: SVBRDF,
    ref: Reference,
    box: tuple[int, int, int, int, int],
    where: str,
    *,
    position: Tensor | None = None,
    focal: float | None = None,
) -> PinnedFlash:
    """The flash measured on the card ``ref`` of the photo's ``square`` ``(3, S, S)`` (linear,
    at the size the maps are made at), with ``network``'s maps of it (one material, any size)
    to judge it by.

    ``box`` is where the square lies in the photo (:func:`svbrdf_models.capture.photos.square_box`);
    ``position`` ``(3,)`` the camera and flash in patch half-widths (default: the Des18 distance
    over the photo's highlight, found with the card ignored). ``focal`` (the lens's focal length
    over half the square's side in pixels, when the lens is known): the phone at ``position`` is
    taken as aimed at the square's centre, and the reading is corrected for the perspective that
    puts a card on the far side of the tilt farther from the flash than its place in the square
    (:func:`svbrdf_render.refinement.falloff.tilted_view_factor`).

    Raises:
        DataError: a region outside the photo or the square, more than 5% clipped or black,
            too dark to read, too small, or one that makes the material's albedo implausible.
    """
    from svbrdf_render import DES18_DISTANCE
    from svbrdf_render.refinement.falloff import tilted_view_factor
    from svbrdf_render.refinement.fit import card_maps, flash_scene, reference_flash
    from svbrdf_render.refinement.rings import highlight_point

    size = square.shape[-1]
    head = f"{where}: --reference {ref.describe()}"
    mask = reference_mask(ref, box, size, where)
    photo = square[None].float()
    point = highlight_point(photo, ignore=mask)
    if position is None:
        position = torch.cat([point[0], photo.new_tensor([DES18_DISTANCE])])
    position = position.reshape(1, 3).to(photo)
    measured = reference_flash(photo, mask, ref.albedo, position)
    _check_readable(measured, head)
    tilt = 1.0 if focal is None else tilted_view_factor(mask, position[0], focal)
    measured = dataclasses.replace(measured, intensity=measured.intensity * tilt)
    card = card_maps(ref.albedo, (size, size))
    level = _network_level(photo, network, card, mask, position, float(measured.intensity[0]))
    _check_level(level, network, mask, head)
    record = {
        "region": [ref.x, ref.y, ref.width, ref.height],
        "albedo": ref.albedo,
        "flash_intensity": float(measured.intensity[0]),
        "flash_color": [round(float(c), 4) for c in measured.color[0]],
        "flash_position": [round(float(c), 4) for c in position[0]],
        "tilt_factor": round(tilt, 4),
        "network_level": level,
        "clipped": round(float(measured.clipped[0]), 4),
        "pixels": int(measured.pixels[0]),
    }
    return PinnedFlash(flash_scene(position, measured.intensity, measured.color), mask, card, record)


def _check_readable(measured, head: str) -> None:
    """Refuse a region too clipped, too dark or too small to read the flash from."""
    clipped, dark, level = float(measured.clipped[0]), float(measured.dark[0]), float(measured.level[0])
    if clipped > CARD_CLIPPED_SHARE:
        raise DataError(
            f"{head}: {clipped:.0%} of the region is clipped (white) in the photo, so the flash read from it "
            f"would be too weak (at most {CARD_CLIPPED_SHARE:.0%} may be); lower the exposure, use a grey "
            "card, or give a region off the highlight that is not blown out"
        )
    if dark > CARD_CLIPPED_SHARE or level < CARD_MIN_LEVEL:
        black = f"{dark:.0%} of it black, " if dark > CARD_CLIPPED_SHARE else ""
        raise DataError(
            f"{head}: the region is too dark to read ({black}mean {level:.4f} of 1, linear; a card needs "
            f"{CARD_MIN_LEVEL}, about 30 of 255): light it with the flash, raise the exposure, or give a "
            "region on the card"
        )
    if int(measured.pixels[0]) < 4:
        raise DataError(f"{head}: too few readable pixels in the region; give a larger region on the card")


def _network_level(photo: Tensor, network: SVBRDF, card: SVBRDF, mask: Tensor, position: Tensor,
                   intensity: float) -> float:  # fmt: skip
    """How many times brighter the measured flash says the material is than ``network``'s maps
    say: the flash those maps need to explain the photo from ``position`` (the median of
    :func:`svbrdf_render.refinement.fit.axis_flash`, the card held at the card) over the flash
    measured. Recorded, and judged (:func:`_check_level`); the maps are not scaled by it: on
    metals and dark materials the network explains much of the photo with its specular lobe,
    and a scale of the diffuse made them worse than the refinement under the measured flash."""
    from svbrdf_render.refinement.fit import axis_flash

    size = photo.shape[-1]
    start = with_card(network.detach().to(torch.float32).resize(size, size), mask, card)
    guessed = axis_flash(start, photo, distance=float(position[0, 2]), over=position[:, :2])
    return float(guessed.point_lights[0].intensity.reshape(-1)[0]) / max(intensity, 1e-12)


def _check_level(level: float, network: SVBRDF, mask: Tensor, head: str) -> None:
    """Refuse a card that makes the material's albedo implausible (:data:`MAX_LEVEL_RATIO`)."""
    luma = network.diffuse.new_tensor((0.2126, 0.7152, 0.0722)).view(1, 3, 1, 1)
    diffuse = network.diffuse.to(torch.float32)
    material = ~(
        torch.nn.functional.interpolate(mask.float(), size=diffuse.shape[-2:], mode="nearest") > 0.5
    )[:, 0]
    scaled = diffuse * level
    white = float((scaled.amax(1) >= 1.0)[material].float().mean())
    specular = (network.specular.to(torch.float32) * luma).sum(1)
    dielectric = material & (specular < METAL_SPECULAR)
    if int(dielectric.sum()) * 2 >= int(material.sum()) and level * AGREES < 1:  # judged: see MIN_MATERIAL
        median = float((scaled * luma).sum(1)[dielectric].median())
    else:
        median = float("inf")
    check = "; check that the region covers only the card (not the material or the highlight) and its albedo"
    if white > MAX_WHITE or level > MAX_LEVEL_RATIO:
        raise DataError(
            f"{head}: the card would make the material {level:.1f} times brighter than the network sees it, "
            f"{white:.0%} of its diffuse white (at most {MAX_LEVEL_RATIO:g} times and "
            f"{MAX_WHITE:.0%} white), which no real capture does{check}"
        )
    if median < MIN_MATERIAL or level < 1 / MAX_LEVEL_RATIO:  # a metal: the ratio alone
        seen = f"median albedo {median:.4f}" if math.isfinite(median) else "its diffuse not judged"
        raise DataError(
            f"{head}: the card would make the material {1 / level:.1f} times darker than the network sees it "
            f"({seen}; at most {MAX_LEVEL_RATIO:g} times, and {MIN_MATERIAL} for a non-metal), "
            f"darker than any real material{check}"
        )
