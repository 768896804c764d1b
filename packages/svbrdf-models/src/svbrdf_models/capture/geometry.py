"""Where the camera stood (its position over the captured square, from the lens and the crop),
and where the flash beside its lens was taken to be.

Maps cover the square a capture takes (``--crop``, or the largest centred one) as the patch
``[-1, 1]^2`` at ``z = 0``; the renderer needs the camera (and the flash beside its lens) in the
same units, half-widths of that square. A pinhole camera looking straight at the surface, its
axis through the photo's centre, sees the square of ``side`` pixels whose top-left corner is at
``(x0, y0)`` (pixels of the photo as displayed, ``W x H``) from::

    x = (W / 2 - (x0 + side / 2)) / (side / 2)        # + right, as the patch's x
    y = -(H / 2 - (y0 + side / 2)) / (side / 2)       # + up: image rows go down
    z = f_px / (side / 2)                             # f_px: the focal length in pixels

so a centred square has the camera on its axis at ``f_px / (side / 2)``, and a crop, which
narrows the field of view, puts it farther away (and to the side when it is off-centre).

The focal length in pixels comes from, in this order (:func:`capture_geometry`):

1. ``distance``: the camera's height in half-widths of the square, on the square's axis
   (``--distance D``): source ``"distance"``;
2. ``fov``: the field of view across the photo's longer side as displayed, in degrees
   (``--fov DEG``): ``f_px = (max(W, H) / 2) / tan(fov / 2)``; source ``"fov"``;
3. the photo's EXIF (read with Pillow): the 35 mm equivalent focal length (FocalLengthIn35mmFilm),
   defined on the diagonal of a 36 x 24 mm frame (43.27 mm), ``f_px = f35 * hypot(W, H) / 43.27``:
   source ``"exif-35mm"``; else the focal length in mm and the sensor's pixel density
   (FocalPlaneXResolution in FocalPlaneResolutionUnit), ``f_px = f_mm * pixels per mm``, scaled
   when the photo was resized since (PixelXDimension): source ``"exif-sensor"``;
4. nothing: source ``"default"``, the capture as before the geometry was read: camera and flash
   at :data:`DEFAULT_DISTANCE` (2.2, the Des18 photos' flash) over the photo's highlight.

A phone's main camera (about 26 mm equivalent, 4:3) puts the camera at about 2.0 half-widths of
the centred square, close to the 2.2 of the photos the networks learnt from.

A flash beside the lens lights the point of the surface right under it most, and less with the
distance from it: with the lens known, the fall-off of that light over the whole photo
(:func:`svbrdf_render.refinement.falloff.fall_off_point`) says where the flash stood over the
square (:func:`place_flash`: the geometry placed there), on a matte material as on a glossy
one. The photo's highlight, found by :func:`svbrdf_render.refinement.rings.find_highlight`, is
recorded beside it, and places the flash of a photo without a known lens (the refinement's
own default) or one a card covers too much of for the fit; a photo without a clear highlight
there gets the flash assumed over the square's centre, or where the lens and the crop place the
camera. :func:`flash_record` says which in material.json's
``flash`` (``placed``, ``highlight``), :func:`flash_line` says it in one line (``predict`` prints
it on stderr), and a highlight :data:`EDGE` half-widths or more from the centre gets a note with
what docs/capture-guide.md measured such a capture to cost (:func:`edge_note`)::

    found = find_point(square, None)                  # (points (1, 2), clear (1,))
    flash = {**flash, **flash_record(found, geometry, options)}
    flash_line(flash), edge_note(flash)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render.scene import DES18_DISTANCE

from ..errors import DataError

__all__ = [
    "DEFAULT_DISTANCE", "DIAGONAL_35MM", "FOV_RANGE", "GEOMETRY_SOURCES", "CaptureGeometry",
    "capture_geometry", "check_distance", "check_fov", "exif_focal", "focal_pixels",
    "EDGE", "EDGE_COST", "PLACES", "edge_note", "find_point", "flash_line", "flash_record", "place_flash",
    "record_flash",
]  # fmt: skip

#: The diagonal of a 35 mm film frame (36 x 24 mm), on which the 35 mm equivalent focal length
#: is defined.
DIAGONAL_35MM = math.hypot(36.0, 24.0)  # 43.27 mm
#: ``--fov`` is refused outside this open range (degrees).
FOV_RANGE = (1.0, 179.0)
#: The camera's height when nothing tells it (the Des18 photos' flash).
DEFAULT_DISTANCE = DES18_DISTANCE
#: Where a geometry came from, most trusted first.
GEOMETRY_SOURCES = ("distance", "fov", "exif-35mm", "exif-sensor", "default")

# EXIF tags (the Exif IFD, 0x8769).
_EXIF_IFD = 0x8769
_FOCAL_35MM = 0xA405
_FOCAL_LENGTH = 0x920A
_FOCAL_PLANE_X = 0xA20E
_FOCAL_PLANE_UNIT = 0xA210
_PIXEL_X = 0xA002
#: Millimetres per FocalPlaneResolutionUnit (2 inch, the default; 3 cm; 4 mm; 5 micrometre).
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}


@dataclass(frozen=True)
class CaptureGeometry:
    """The camera over a captured square, and the figures it came from.

    Attributes:
        position: ``(x, y, z)``, the camera's lens (and the flash beside it) in half-widths of the
            captured square, from the square's centre (x right, y up, z out of the surface).
            With source ``"default"``: ``(0, 0, 2.2)``, whose x and y the capture replaces by the
            photo's highlight (:func:`svbrdf_render.refinement.rings.highlight_point`).
        source: one of :data:`GEOMETRY_SOURCES`.
        focal_px: the focal length in pixels of the photo as displayed (None for ``"distance"``
            and ``"default"``).
        focal_mm, focal_35mm: the EXIF focal length and its 35 mm equivalent, when the file has them.
        fov: the field of view across the photo's longer side, degrees (None without ``focal_px``).
        photo_size: ``(W, H)`` of the photo as displayed (after its EXIF orientation).
        square: ``(x0, y0, side)``: the captured square in those pixels.
    """

    position: tuple[float, float, float]
    source: str
    focal_px: float | None = None
    focal_mm: float | None = None
    focal_35mm: float | None = None
    fov: float | None = None
    photo_size: tuple[int, int] | None = None
    square: tuple[int, int, int] | None = None
    over: str | None = None
    """Where x and y came from once placed (:meth:`over_highlight`): "fall-off", "highlight" or
    "square"."""
    misfit: float | None = None
    """With ``over == "fall-off"``: how far the photo departs from a flat material's fall-off
    there (:func:`svbrdf_render.refinement.falloff.fall_off_point`)."""

    @property
    def distance(self) -> float:
        """The camera's distance from the square's centre, in half-widths."""
        return math.sqrt(sum(v * v for v in self.position))

    @property
    def known(self) -> bool:
        """Whether the position is the photo's own (not the default's guess)."""
        return self.source != "default"

    def square_focal(self) -> float | None:
        """The lens's focal length over half the square's side (both in the photo's pixels) when
        the camera was placed by the fall-off (off the axis, aimed at the square's centre), else
        None: what :func:`svbrdf_render.refinement.falloff.tilted_view_factor` takes."""
        if self.over != "fall-off" or not self.focal_px or not self.square:
            return None
        return float(self.focal_px) / (self.square[2] / 2)

    def over_highlight(self, photo, ignore=None, found=None) -> CaptureGeometry:
        """This geometry with x and y where the flash stood over the square ``photo`` ``(3, S, S)``
        (linear; ``ignore``: a reference card's pixels), at the distance from the square's centre
        the lens gives (so lower than it when off the axis, as a tilted phone's flash is). A tilted or
        off-centre phone moves its flash off the square's axis (a 20 degree tilt: 0.7
        half-widths), which the lens and the crop alone cannot know. The place is read off the
        fall-off of the flash's light over the whole photo
        (:func:`~svbrdf_render.refinement.falloff.fall_off_point`: ``over`` "fall-off"), which a
        matte material shows as well as a glossy one; on the simulated handheld photos of
        docs/measured-shots.md it lay 0.01-0.24 half-widths from the true flash, where the
        photo's brightest blurred point (``found``, :func:`~svbrdf_render.refinement.rings.
        find_highlight`, computed when None) missed by up to 0.43 and, on a bright card's edge,
        by 1.6. A photo too covered by ``ignore`` for the fit is placed over its clear
        highlight ("highlight"), else left as it is ("square"). For ``--distance`` (the user
        says the camera stood on the square's axis) and the default geometry (the refinement
        places its flash over the highlight itself), as it is."""
        import dataclasses

        from svbrdf_render.refinement.falloff import fall_off_point
        from svbrdf_render.refinement.rings import find_highlight

        if self.source in ("default", "distance"):
            return self
        height = self.position[2]
        around = torch.tensor(self.position[:2])
        point, misfit = fall_off_point(photo[None].float(), height, ignore, around=around)
        if math.isfinite(float(misfit[0])):
            x, y = (float(v) for v in point[0])
            # The lens gives the distance to the square's centre, which a tilted phone keeps while
            # its flash moves off the axis: the flash stands lower than that distance (a fifth of
            # it at most, for a flash beyond the square's corner).
            z = math.sqrt(max(self.distance**2 - x * x - y * y, (0.8 * self.distance) ** 2))
            return dataclasses.replace(self, position=(x, y, z), over="fall-off", misfit=float(misfit[0]))
        point, clear = found if found is not None else find_highlight(photo[None].float(), ignore)
        if not bool(clear[0]):
            return dataclasses.replace(self, over="square")
        x, y = (float(v) for v in point[0])
        return dataclasses.replace(self, position=(x, y, height), over="highlight")

    def record(self, used: bool) -> dict:
        """material.json's ``geometry`` section; ``used``: the refinement's camera and flash
        stood at ``position`` (over the highlight for ``"default"``)."""

        def r(v, digits=4):
            return None if v is None else round(float(v), digits)

        return {
            "source": self.source,
            "position": None if not self.known else [r(v) for v in self.position],
            "distance": r(self.distance if self.known else self.position[2]),
            "over": self.over or ("square" if self.known else "highlight"),
            "fall_off_misfit": r(self.misfit),
            "units": "half-widths of the captured square, from its centre; x right, y up, z out",
            "fov": r(self.fov, 3),
            "focal_length_px": r(self.focal_px, 2),
            "focal_length_mm": r(self.focal_mm, 3),
            "focal_length_35mm": r(self.focal_35mm, 3),
            "photo_size": list(self.photo_size) if self.photo_size else None,
            "square": list(self.square) if self.square else None,
            "used": bool(used),
        }


def check_fov(fov) -> float:
    """``fov`` (degrees) as a float, or a :class:`DataError` naming ``--fov`` and the value when it
    is not a finite number strictly between 1 and 179."""
    lo, hi = FOV_RANGE
    try:
        value = float(fov)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(fov, bool) or not (math.isfinite(value) and lo < value < hi):
        raise DataError(
            f"--fov {fov}: the field of view across the photo's longer side must be a number of "
            f"degrees between {lo:g} and {hi:g}"
        )
    return value


def check_distance(distance) -> float:
    """``distance`` (half-widths) as a float, or a :class:`DataError` naming ``--distance`` and the
    value when it is not a finite number > 0."""
    try:
        value = float(distance)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(distance, bool) or not (math.isfinite(value) and value > 0):
        raise DataError(
            f"--distance {distance}: the camera's height must be a finite number > 0 of half-widths "
            "of the captured square"
        )
    return value


def check_geometry_options(fov, distance) -> tuple[float | None, float | None]:
    """``(fov, distance)`` checked (None stays None); both at once is a :class:`DataError`."""
    if fov is not None and distance is not None:
        raise DataError(
            f"--fov {fov} and --distance {distance}: give one (--distance sets the camera's height, "
            "--fov derives it from the lens)"
        )
    return (None if fov is None else check_fov(fov)), (None if distance is None else check_distance(distance))


def _positive(value) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def exif_focal(path) -> dict:
    """The focal-length figures of a photo's EXIF: ``focal_35mm``, ``focal_mm``, ``plane_x``
    (FocalPlaneXResolution), ``plane_unit``, ``pixel_x`` (PixelXDimension), ``width`` and
    ``height`` (as stored), each None when absent, zero or unreadable. A damaged EXIF block
    reads as none."""
    from PIL import Image

    out = dict.fromkeys(("focal_35mm", "focal_mm", "plane_x", "plane_unit", "pixel_x"))
    with Image.open(path) as im:
        out["width"], out["height"] = im.size
        try:
            ifd = im.getexif().get_ifd(_EXIF_IFD)
        except Exception:  # a damaged EXIF block: no figures
            return out
    out["focal_35mm"] = _positive(ifd.get(_FOCAL_35MM))
    out["focal_mm"] = _positive(ifd.get(_FOCAL_LENGTH))
    out["plane_x"] = _positive(ifd.get(_FOCAL_PLANE_X))
    unit = _positive(ifd.get(_FOCAL_PLANE_UNIT))
    out["plane_unit"] = int(unit) if unit is not None else None
    pixel_x = _positive(ifd.get(_PIXEL_X))
    out["pixel_x"] = int(pixel_x) if pixel_x is not None else None
    return out


def focal_pixels(exif: dict) -> tuple[float, str] | None:
    """``(f_px, source)`` from :func:`exif_focal`'s figures: the 35 mm equivalent on the diagonal
    (``"exif-35mm"``), else the focal length times the sensor's pixel density (``"exif-sensor"``,
    scaled by ``width / PixelXDimension`` when the photo was resized after the camera wrote it);
    None when neither is there."""
    w, h = exif["width"], exif["height"]
    if exif["focal_35mm"] is not None:
        return exif["focal_35mm"] * math.hypot(w, h) / DIAGONAL_35MM, "exif-35mm"
    unit_mm = _UNIT_MM.get(exif["plane_unit"] if exif["plane_unit"] is not None else 2)
    if exif["focal_mm"] is None or exif["plane_x"] is None or unit_mm is None:
        return None
    f_px = exif["focal_mm"] * exif["plane_x"] / unit_mm
    if exif["pixel_x"] is not None and exif["pixel_x"] != w:  # resized since: the density scales
        f_px *= w / exif["pixel_x"]
    return f_px, "exif-sensor"


def capture_geometry(path, crop: tuple[int, int, int] | None = None, *, fov: float | None = None,
                     distance: float | None = None) -> CaptureGeometry:  # fmt: skip
    """The camera over the square a capture of ``path`` takes (``crop``, as ``--crop``, else the
    centred square): from ``distance``, else ``fov``, else the photo's EXIF, else the default
    (see the module). Bad ``fov`` or ``distance``, or both: a :class:`DataError` (one line)."""
    from .photos import square_box

    fov, distance = check_geometry_options(fov, distance)
    x0, y0, side, width, height = square_box(Path(path), crop)
    box, size, half = (x0, y0, side), (width, height), side / 2
    if distance is not None:
        return CaptureGeometry((0.0, 0.0, distance), "distance", photo_size=size, square=box)
    exif = exif_focal(path)
    f35, fmm = exif["focal_35mm"], exif["focal_mm"]
    if fov is not None:
        f_px, source = (max(width, height) / 2) / math.tan(math.radians(fov) / 2), "fov"
    else:
        found = focal_pixels(exif)
        if found is None:
            return CaptureGeometry((0.0, 0.0, DEFAULT_DISTANCE), "default", focal_mm=fmm, focal_35mm=f35,
                                   photo_size=size, square=box)  # fmt: skip
        f_px, source = found
    x = (width / 2 - (x0 + half)) / half + 0.0  # + 0.0: no -0.0 in material.json
    y = (y0 + half - height / 2) / half + 0.0
    seen = fov if fov is not None else math.degrees(2 * math.atan((max(width, height) / 2) / f_px))
    return CaptureGeometry((x, y, f_px / half), source, focal_px=f_px, focal_mm=fmm, focal_35mm=f35,
                           fov=seen, photo_size=size, square=box)  # fmt: skip


# -- the flash: over the photo's highlight, or assumed ------------------------------------------

#: A highlight this many half-widths of the square from its centre, or more, is warned about:
#: the off-centre row of docs/capture-guide.md's "What each mistake costs" (the phone 0.6
#: half-widths to the side, the highlight found and the flash put over it) measured it to cost
#: :data:`EDGE_COST` against a capture over the centre, the smallest offset measured.
EDGE = 0.6
#: That row's cost, quoted in the note (tests/models/test_models_flash_point.py checks the docs).
EDGE_COST = "diffuse +22%, re-rendering +34%"

#: material.json's ``flash.placed``: how the flash's x and y over the square were chosen.
PLACES = {
    "fall-off": "where the fall-off of its light over the photo puts it",
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
    :class:`~svbrdf_models.capture.one.CaptureOptions`) at ``geometry`` (a :class:`CaptureGeometry`),
    ``found`` by :func:`find_point`."""
    point, clear = found
    seen = bool(clear[0])
    x, y = (round(float(v), 4) for v in point[0])
    if not options.refine:
        placed = "fitted"
    elif options.scene is not None:
        placed = "scene"
    elif geometry.source == "distance":
        placed = "distance"
    elif geometry.over == "fall-off":
        placed = "fall-off"
    else:
        placed = "highlight" if seen else ("lens" if geometry.known else "centre")
    highlight = {"found": seen, "point": [x, y] if seen else None,
                 "off_centre": round(math.hypot(x, y), 4) if seen else None}  # fmt: skip
    return {"placed": placed, "highlight": highlight}


def place_flash(photo: Tensor, card: Tensor | None, geometry, options):
    """``(geometry, found)``: the capture's square ``photo``'s highlight (:func:`find_point`;
    ``card``: a reference card's pixels, ignored), and ``geometry`` placed over it when clear
    (:meth:`CaptureGeometry.over_highlight`)."""
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
    at = flash.get("position") or [None, None]
    if placed == "fall-off" and None not in at[:2]:
        return f"flash at x {at[0]:+.2f}, y {at[1]:+.2f}, {PLACES[placed]}; {seen}"
    if placed == "highlight":
        return f"flash taken over its {seen}"
    if placed in ("centre", "lens"):
        where = f" (x {at[0]:+.2f}, y {at[1]:+.2f})" if placed == "lens" and None not in at[:2] else ""
        return f"{seen}: the flash {PLACES[placed]}{where}"
    return f"flash {PLACES.get(placed, 'where the capture put it')}; {seen}"


def edge_note(flash: dict) -> str | None:
    """A note when the flash stood :data:`EDGE` half-widths or more from the square's centre (placed
    by its fall-off: where it stood; else the photo's highlight), with what docs/capture-guide.md
    measured that to cost; None otherwise."""
    at = flash.get("position") or [None, None]
    if flash.get("placed") == "fall-off" and None not in at[:2]:
        r, what, where = math.hypot(at[0], at[1]), "flash stood", "under the flash"
    else:
        r = (flash.get("highlight") or {}).get("off_centre")
        what, where = "flash's highlight is", "around the highlight"
    if r is None or r < EDGE:
        return None
    return (
        f"the {what} {r:.2f} half-widths from the centre of the square, near its edge: a "
        f"flash {EDGE:g} half-widths off the centre cost {EDGE_COST} error, measured on rendered photos "
        "(docs/capture-guide.md, What each mistake costs); hold the phone over the centre of the "
        f"material, or --crop a square {where}"
    )
