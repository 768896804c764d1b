"""Where a capture took the flash to be, whether the photo showed it, and what a highlight near
the edge of the captured square costs.

A flash beside the lens lights the point of the surface right under it: the photo's highlight,
found by :func:`svbrdf_render.refinement.rings.find_highlight`, says where the flash stood over
the square. A photo without a clear one (a rough, dark or strongly textured material) gets the
flash assumed over the square's centre, or where the lens and the crop place the camera.
:func:`flash_record` says which in material.json's ``flash`` (``placed``, ``highlight``),
:func:`flash_line` says it in one line (``predict`` prints it on stderr), and a highlight
:data:`EDGE` half-widths or more from the centre gets a note with what
docs/capture-guide.md measured such a capture to cost (:func:`edge_note`)::

    found = find_point(square, None)                  # (points (1, 2), clear (1,))
    flash = {**flash, **flash_record(found, geometry, options)}
    flash_line(flash), edge_note(flash)
"""

from __future__ import annotations

import math

from torch import Tensor

__all__ = [
    "EDGE", "EDGE_COST", "PLACES", "edge_note", "find_point", "flash_line", "flash_record", "place_flash",
    "record_flash",
]  # fmt: skip

#: A highlight this many half-widths of the square from its centre, or more, is warned about:
#: the off-centre row of docs/capture-guide.md's "What each mistake costs" (the phone 0.6
#: half-widths to the side, the highlight found and the flash put over it) measured it to cost
#: :data:`EDGE_COST` against a capture over the centre, the smallest offset measured.
EDGE = 0.6
#: That row's cost, quoted in the note (tests/models/test_models_flash_point.py checks the docs).
EDGE_COST = "diffuse +22%, re-rendering +34%"

#: material.json's ``flash.placed``: how the flash's x and y over the square were chosen.
PLACES = {
    "highlight": "over the photo's highlight",
    "centre": "assumed over the centre of the square",
    "lens": "where the lens and the crop place the camera",
    "distance": "over the centre of the square (--distance)",
    "scene": "where --scene puts it",
    "fitted": "fitted to the network's maps (--refine 0)",
}

def find_point(photo: Tensor, ignore: Tensor | None) -> tuple[Tensor, Tensor]:
    """:func:`~svbrdf_render.refinement.rings.find_highlight` of the square ``photo`` ``(3, S, S)``
    (``ignore``: ``(1, 1, S, S)``, a reference card's pixels): ``(points (1, 2), clear (1,))``.
    The search itself works at a bounded size, so it costs the same at every photo size."""
    from svbrdf_render.refinement.rings import find_highlight

    return find_highlight(photo[None].float(), ignore)


def flash_record(found: tuple[Tensor, Tensor], geometry, options) -> dict:
    """material.json's ``flash.placed`` (a key of :data:`PLACES`) and ``flash.highlight`` (``found``,
    ``point`` x and y in half-widths from the square's centre, x right and y up, or None, and
    ``off_centre``, its distance from the centre) for a capture with ``options`` (a
    :class:`~svbrdf_models.capture.one.CaptureOptions`) at ``geometry`` (a
    :class:`~svbrdf_models.capture.geometry.CaptureGeometry`), ``found`` by :func:`find_point`."""
    point, clear = found
    seen = bool(clear[0])
    x, y = (round(float(v), 4) for v in point[0])
    if not options.refine:
        placed = "fitted"
    elif options.scene is not None:
        placed = "scene"
    elif geometry.source == "distance":
        placed = "distance"
    else:
        placed = "highlight" if seen else ("lens" if geometry.known else "centre")
    highlight = {"found": seen, "point": [x, y] if seen else None,
                 "off_centre": round(math.hypot(x, y), 4) if seen else None}  # fmt: skip
    return {"placed": placed, "highlight": highlight}


def place_flash(photo: Tensor, card: Tensor | None, geometry, options):
    """``(geometry, found)``: the capture's square ``photo``'s highlight (:func:`find_point`;
    ``card``: a reference card's pixels, ignored), and
    ``geometry`` placed over it when clear
    (:meth:`~svbrdf_models.capture.geometry.CaptureGeometry.over_highlight`)."""
    found = find_point(photo, card)  # a refinement's own point
    return geometry.over_highlight(photo, card, found), found


def record_flash(flash: dict, found: tuple[Tensor, Tensor], geometry, options) -> list[str]:
    """A capture entry's ``flash`` given :func:`flash_record`'s fields (how it was placed, the
    highlight); the note of a highlight near the square's edge (:func:`edge_note`), if any."""
    flash.update(flash_record(found, geometry, options))
    return [n for n in (edge_note(flash),) if n]


def flash_line(flash: dict) -> str:
    """One line: where the flash was taken to be and whether the photo showed its highlight."""
    h = flash.get("highlight") or {}
    point = h.get("point") if h.get("found") else None
    seen = (
        f"highlight found at x {point[0]:+.2f}, y {point[1]:+.2f} (half-widths from the square's centre)"
        if point else "no clear highlight in the photo"
    )  # fmt: skip
    placed = flash.get("placed")
    if placed == "highlight":
        return f"flash taken over its {seen}"
    if placed in ("centre", "lens"):
        at = flash.get("position") or [None, None]
        where = f" (x {at[0]:+.2f}, y {at[1]:+.2f})" if placed == "lens" and None not in at[:2] else ""
        return f"{seen}: the flash {PLACES[placed]}{where}"
    return f"flash {PLACES.get(placed, 'where the capture put it')}; {seen}"


def edge_note(flash: dict) -> str | None:
    """A note when the photo's highlight lies :data:`EDGE` half-widths or more from the square's
    centre, with what docs/capture-guide.md measured that to cost; None otherwise."""
    r = (flash.get("highlight") or {}).get("off_centre")
    if r is None or r < EDGE:
        return None
    return (
        f"the flash's highlight is {r:.2f} half-widths from the centre of the square, near its edge: a "
        f"flash {EDGE:g} half-widths off the centre cost {EDGE_COST} error, measured on rendered photos "
        "(docs/capture-guide.md, What each mistake costs); hold the phone over the centre of the "
        "material, or --crop a square around the highlight"
    )
