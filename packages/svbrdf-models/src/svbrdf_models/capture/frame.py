"""The printed capture frame: a sheet with fiducial markers around a square window.

The user prints the frame (``svbrdf-models frame -o frame.pdf``: :func:`write_frame`), cuts out
the window, lays the sheet flat on the material and takes flash photos with the whole frame in
the picture. In each photo :mod:`~svbrdf_models.capture.framephoto` finds the markers; from them
come the window rectified into the material's square, the camera's and the flash's positions
over it and the pixels of the reference strip, whose albedo the user states (the shot's
exposure follows from them).

:class:`FrameLayout` is the one declaration of the sheet: everything drawn on it and everything
looked for in a photo comes from it. Coordinates on the sheet are in cm in *the frame's plane*:
origin at the window's centre, x right, y up (towards the title), z out of the paper. The
material's square, the patch ``[-1, 1]^2`` of the renderer, is the window: one unit is half the
window's side.

Markers: AprilTag 36h11 (``cv2.aruco.DICT_APRILTAG_36h11``). Its 587 codes differ in at least 11
of 36 bits, so a texture inside the window (a tile's grid, a printed pattern) practically never
decodes as one, where the 4x4 ArUco codes (16 bits) do now and then; and there are enough codes
to give every window size its own eight (:attr:`FrameLayout.marker_ids`), so that a photo of a
frame printed at another size is recognised as such instead of being measured at the wrong
scale. Eight markers (the window's corners and the middles of its sides) leave enough visible
when a hand or the material covers some: :data:`MIN_MARKERS` are needed.

OpenCV (``opencv-python-headless``, the ``photo`` extra) draws the markers' codes here and finds
them in photos; it is imported only by the functions that need it, and its absence is a
:class:`~svbrdf_models.errors.DataError` saying how to install it. Pillow (same extra) draws the
sheet.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError

__all__ = [
    "DEFAULT_DPI",
    "FLASH_OFFSET_CM",
    "FrameLayout",
    "MIN_MARKERS",
    "PAPERS",
    "draw_frame",
    "write_frame",
]

#: Paper sizes in cm (width, height), portrait.
PAPERS = {"a4": (21.0, 29.7), "letter": (21.59, 27.94)}
#: Nothing is drawn closer than this to the paper's edge (printers leave 3 to 6 mm unprinted).
MARGIN_CM = 1.0
#: Window sides offered: from MIN to MAX cm in steps of STEP (each has its own marker ids).
MIN_WINDOW_CM, MAX_WINDOW_CM, WINDOW_STEP_CM = 4.0, 14.0, 0.5
#: Markers per frame, and the fewest of them a photo must show: the homography needs 4 points
#: (one marker has them), but a 2 cm marker extrapolated over a 10 cm window multiplies its
#: corners' error about five times, and with three markers around the window one that is
#: misread is outvoted.
MARKERS_PER_FRAME = 8
MIN_MARKERS = 3
#: The dictionary's name in cv2.aruco, and how many codes it has.
DICTIONARY, DICTIONARY_SIZE = "DICT_APRILTAG_36h11", 587
#: Resolution of the drawn sheet unless told otherwise (dots per inch).
DEFAULT_DPI = 300
#: The flash's position beside the lens by default, in cm along the photo's x (right) and y (up)
#: as the photo is shown: most phones' flash is 0.8 to 1.5 cm from the main lens. Measure yours.
FLASH_OFFSET_CM = (1.0, 0.0)
#: The ruler printed to check the print's scale (cm).
RULER_CM = 5
_CM_PER_INCH = 2.54
#: Heights (cm) reserved above the markers for the title and below the strip for the notes.
_TITLE_CM, _NOTES_CM = 1.7, 4.4
#: The parts every frame shares (cm): marker side, white gap around the window (and above the
#: strip), the strip's height. A frame's ids say its window; these say the rest.
_MARKER_CM, _GAP_CM, _STRIP_CM = 2.0, 0.4, 1.5
_INSTALL = "pip install 'svbrdf-models[photo]'"


def require_opencv():
    """OpenCV, or a DataError saying how to install it."""
    try:
        import cv2
    except ImportError:
        raise DataError(f"the printed frame needs OpenCV (opencv-python-headless): {_INSTALL}") from None
    return cv2


def _pil():
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError:
        raise DataError(f"drawing the frame needs Pillow: {_INSTALL}") from None
    return Image, ImageDraw, ImageFont


@dataclass(frozen=True)
class FrameLayout:
    """The printed frame: where every marker, the window and the reference strip are, in cm in
    the frame's plane (origin at the window's centre, x right, y up).

    ``window_cm`` (the window's side) and ``paper`` are chosen; the rest is fixed for every
    frame, so that a frame's marker ids alone say its geometry. Markers are ``marker_cm`` wide
    (black border included), ``gap_cm`` of white paper from the window's edge (AprilTag needs a
    white border of one cell, 0.25 cm); the strip is a band of unprinted paper ``strip_cm`` high
    under the bottom markers, as wide as the markers' ring.
    """

    window_cm: float = 10.0
    paper: str = "a4"
    marker_cm: float = field(default=_MARKER_CM, init=False)
    gap_cm: float = field(default=_GAP_CM, init=False)
    strip_cm: float = field(default=_STRIP_CM, init=False)
    dictionary: str = field(default=DICTIONARY, init=False)

    def __post_init__(self):
        if self.paper not in PAPERS:
            raise DataError(f"unknown paper {self.paper!r}; choose one of {', '.join(PAPERS)}")
        w = self.window_cm
        steps = (w - MIN_WINDOW_CM) / WINDOW_STEP_CM if isinstance(w, (int, float)) else float("nan")
        offered = math.isfinite(steps) and abs(steps - round(steps)) < 1e-6
        if not (offered and MIN_WINDOW_CM <= w <= MAX_WINDOW_CM):
            raise DataError(
                f"a window of {w} cm is not offered: choose {MIN_WINDOW_CM:g} to {MAX_WINDOW_CM:g} cm in "
                f"steps of {WINDOW_STEP_CM:g} cm (each size has its own markers)"
            )
        largest = self.largest_window_cm(self.paper)
        if w > largest + 1e-9:
            raise DataError(
                f"a window of {w:g} cm does not fit on {self.paper} paper with the markers, the strip "
                f"and the notes: at most {largest:g} cm"
            )

    @staticmethod
    def largest_window_cm(paper: str) -> float:
        """The largest offered window whose frame fits on ``paper``."""
        width, height = PAPERS[paper]
        fixed_w = 2 * (_GAP_CM + _MARKER_CM)  # gap and marker on each side
        fixed_h = fixed_w + _GAP_CM + _STRIP_CM + _TITLE_CM + _NOTES_CM  # + strip gap, strip, text
        room = min(width - 2 * MARGIN_CM - fixed_w, height - 2 * MARGIN_CM - fixed_h, MAX_WINDOW_CM)
        return MIN_WINDOW_CM + math.floor((room - MIN_WINDOW_CM) / WINDOW_STEP_CM + 1e-9) * WINDOW_STEP_CM

    # --- identity -------------------------------------------------------------------------
    @property
    def layout_id(self) -> int:
        """This frame's number: its window size's place among the offered sizes."""
        return round((self.window_cm - MIN_WINDOW_CM) / WINDOW_STEP_CM)

    @property
    def marker_ids(self) -> tuple[int, ...]:
        """The eight AprilTag ids of this frame, in the order of :attr:`marker_centres`."""
        first = MARKERS_PER_FRAME * self.layout_id
        return tuple(range(first, first + MARKERS_PER_FRAME))

    @staticmethod
    def window_of_id(marker_id: int) -> float | None:
        """The window side (cm) of the frame a marker id belongs to, or None for an id no frame uses."""
        k = int(marker_id) // MARKERS_PER_FRAME
        w = MIN_WINDOW_CM + k * WINDOW_STEP_CM
        return w if 0 <= marker_id and w <= MAX_WINDOW_CM else None

    def describe(self) -> str:
        ids = self.marker_ids
        return f"the {self.window_cm:g} cm frame (AprilTag 36h11 ids {ids[0]}-{ids[-1]})"

    # --- geometry in the frame's plane (cm) ----------------------------------------------
    @property
    def half_width_cm(self) -> float:
        """Half the window's side: one unit of the material's square."""
        return self.window_cm / 2

    @property
    def ring_cm(self) -> float:
        """Distance from the window's centre to the centre line of the markers' ring."""
        return self.window_cm / 2 + self.gap_cm + self.marker_cm / 2

    @property
    def marker_centres(self) -> np.ndarray:
        """(8, 2): each marker's centre, clockwise from the top-left corner of the window."""
        c = self.ring_cm
        return np.array(
            [(-c, c), (0, c), (c, c), (c, 0), (c, -c), (0, -c), (-c, -c), (-c, 0)], dtype=np.float64
        )

    @property
    def marker_corners(self) -> np.ndarray:
        """(8, 4, 2): each marker's corners in the order cv2.aruco reports them for an upright
        marker: top-left, top-right, bottom-right, bottom-left."""
        h = self.marker_cm / 2
        offsets = np.array([(-h, h), (h, h), (h, -h), (-h, -h)])
        return self.marker_centres[:, None, :] + offsets[None]

    @property
    def window_corners(self) -> np.ndarray:
        """(4, 2): the window's corners, top-left, top-right, bottom-right, bottom-left."""
        h = self.half_width_cm
        return np.array([(-h, h), (h, h), (h, -h), (-h, -h)], dtype=np.float64)

    @property
    def strip_rect(self) -> tuple[float, float, float, float]:
        """The reference strip (x0, y0, x1, y1) in cm: under the bottom markers, as wide as the ring."""
        outer = self.ring_cm + self.marker_cm / 2
        top = -(outer + self.gap_cm)
        return (-outer, top - self.strip_cm, outer, top)

    @property
    def strip_corners(self) -> np.ndarray:
        """(4, 2): the strip's corners, top-left, top-right, bottom-right, bottom-left."""
        x0, y0, x1, y1 = self.strip_rect
        return np.array([(x0, y1), (x1, y1), (x1, y0), (x0, y0)], dtype=np.float64)

    @property
    def origin_on_page_cm(self) -> tuple[float, float]:
        """Where the window's centre is on the sheet, in cm from its top-left corner (x right,
        y down): centred across, the title, frame, strip and notes centred down."""
        width, height = PAPERS[self.paper]
        top = self.ring_cm + self.marker_cm / 2 + _TITLE_CM
        bottom = -self.strip_rect[1] + _NOTES_CM
        return width / 2, (height - top - bottom) / 2 + top


# --- drawing --------------------------------------------------------------------------------
def _marker_bits(marker_id: int) -> np.ndarray:
    """The marker's cells, black border included (8 x 8 for 36h11): 0 black, 255 white."""
    cv2 = require_opencv()
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
    cells = dictionary.markerSize + 2
    return cv2.aruco.generateImageMarker(dictionary, int(marker_id), cells, borderBits=1)


class _Sheet:
    """A sheet being drawn: frame-plane cm to page pixels, fonts and lines at its resolution."""

    def __init__(self, layout: FrameLayout, dpi: int):
        self.layout, self.scale = layout, dpi / _CM_PER_INCH  # pixels per cm
        self.width_cm, height_cm = PAPERS[layout.paper]
        self.origin = layout.origin_on_page_cm
        shape = (round(height_cm * self.scale), round(self.width_cm * self.scale))
        self.pixels = np.full(shape, 255, np.uint8)
        self.line = max(1, round(0.03 * self.scale))  # 0.3 mm

    def px(self, x: float, y: float) -> tuple[float, float]:
        """Frame cm -> page pixels (continuous: pixel (0, 0) covers [0, 1)^2)."""
        return (self.origin[0] + x) * self.scale, (self.origin[1] - y) * self.scale

    def font(self, cm: float):
        return _pil()[2].load_default(size=max(6, round(cm * self.scale)))


def draw_frame(layout: FrameLayout, dpi: int = DEFAULT_DPI):
    """The sheet as a greyscale Pillow image at ``dpi``, the paper's size: markers, the window's
    cut line, the strip's outline, the title (the window's size), a 5 cm ruler and the notes.

    Each marker cell's edges fall on the nearest pixel of their true position (within half a
    pixel: 0.04 mm at 300 dpi)."""
    Image, ImageDraw, _ = _pil()
    sheet = _Sheet(layout, dpi)
    _draw_markers(sheet)
    image = Image.fromarray(sheet.pixels, mode="L")
    draw = ImageDraw.Draw(image)
    _draw_window_and_strip(sheet, draw)
    _draw_notes(sheet, draw)
    return image


def _draw_markers(sheet: _Sheet) -> None:
    layout = sheet.layout
    side = layout.marker_cm * sheet.scale
    for marker_id, (cx, cy) in zip(layout.marker_ids, layout.marker_centres, strict=True):
        bits = _marker_bits(marker_id)
        n = bits.shape[0]
        x0, y0 = sheet.px(cx - layout.marker_cm / 2, cy + layout.marker_cm / 2)
        cols = np.arange(round(x0), round(x0 + side))
        rows = np.arange(round(y0), round(y0 + side))
        ci = np.clip(np.floor((cols + 0.5 - x0) / side * n).astype(int), 0, n - 1)
        ri = np.clip(np.floor((rows + 0.5 - y0) / side * n).astype(int), 0, n - 1)
        sheet.pixels[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] = bits[np.ix_(ri, ci)]


def _draw_window_and_strip(sheet: _Sheet, draw) -> None:
    """The window's cut line (dashed) with a word inside, and the strip's outline."""
    half, scale = sheet.layout.half_width_cm, sheet.scale
    (wl, wt), (wr, wb) = sheet.px(-half, half), sheet.px(half, -half)
    dash = 0.4 * scale
    sides = ((wl, wr, wt, True), (wl, wr, wb, True), (wt, wb, wl, False), (wt, wb, wr, False))
    for a0, a1, fixed, horizontal in sides:
        t = a0
        while t < a1:
            end = min(t + dash, a1)
            xy = [(t, fixed), (end, fixed)] if horizontal else [(fixed, t), (fixed, end)]
            draw.line(xy, fill=0, width=sheet.line)
            t += 2 * dash
    small = sheet.font(0.32)
    cx, cy = sheet.px(0, 0)
    draw.text((cx, cy), "cut out the window", fill=140, font=small, anchor="mm")
    hint = "(top of the maps: the title's side)"
    draw.text((cx, cy + 0.6 * scale), hint, fill=140, font=small, anchor="mm")
    x0, y0, x1, y1 = sheet.layout.strip_rect  # unprinted paper inside a thin outline
    draw.rectangle([*sheet.px(x0, y1), *sheet.px(x1, y0)], outline=0, width=sheet.line)


def _draw_notes(sheet: _Sheet, draw) -> None:
    """The title above the markers; under the strip its note, the ruler and how to use the sheet."""
    layout, scale = sheet.layout, sheet.scale
    cx, top = sheet.px(0, layout.ring_cm + layout.marker_cm / 2)
    ids, w = layout.marker_ids, layout.window_cm
    title = f"Capture frame: window {w:g} cm x {w:g} cm"
    draw.text((cx, top - 1.05 * scale), title, fill=0, font=sheet.font(0.6), anchor="ms")
    draw.text(
        (cx, top - 0.35 * scale),
        f"svbrdf-models frame, AprilTag 36h11 markers {ids[0]}-{ids[-1]}; this side is the top of the maps",
        fill=0,
        font=sheet.font(0.32),
        anchor="ms",
    )
    body = sheet.font(0.34)
    text_width = (sheet.width_cm - 2 * MARGIN_CM) * scale
    y = sheet.px(0, layout.strip_rect[1])[1] + 0.55 * scale
    y = _paragraph(
        draw,
        body,
        cx,
        y,
        text_width,
        "Reference strip (above): leave it white or glue a matte grey card on it; measure or state "
        "its albedo (plain printer paper is about 0.8, an 18% grey card 0.18).",
        scale,
    )
    y += 0.35 * scale  # the ruler: RULER_CM cm with cm and half-cm ticks, centred
    r0 = cx - RULER_CM / 2 * scale
    draw.line([(r0, y), (r0 + RULER_CM * scale, y)], fill=0, width=sheet.line)
    for k in range(2 * RULER_CM + 1):
        xk = r0 + k / 2 * scale
        draw.line([(xk, y), (xk, y + (0.35 if k % 2 == 0 else 0.2) * scale)], fill=0, width=sheet.line)
    label = (r0 + (RULER_CM + 0.3) * scale, y + 0.3 * scale)
    draw.text(label, f"{RULER_CM} cm", fill=0, font=body, anchor="ls")
    _paragraph(
        draw,
        body,
        cx,
        y + 0.85 * scale,
        text_width,
        f"Print at 100% (actual size: no scaling, no 'fit to page'): the ruler must measure {RULER_CM} cm "
        f"and the window {w:g} cm. Cut out the window, lay the sheet flat on the material "
        "with the window over the part to capture, and take flash photos from above with every marker "
        "and the strip in the picture.",
        scale,
    )


def _paragraph(draw, font, cx: float, y: float, width: float, text: str, scale: float) -> float:
    """Draw ``text`` centred at ``cx`` from ``y`` down, wrapped to ``width`` pixels; the y below it."""
    words = text.split()
    lines, current = [], ""
    for word in words:
        trial = f"{current} {word}".strip()
        if current and font.getlength(trial) > width:
            lines.append(current)
            current = word
        else:
            current = trial
    lines.append(current)
    for text_line in lines:
        draw.text((cx, y), text_line, fill=0, font=font, anchor="mt")
        y += 0.5 * scale
    return y


def write_frame(path: str | os.PathLike, layout: FrameLayout, dpi: int = DEFAULT_DPI) -> Path:
    """Draw the frame and write it to ``path`` (``.pdf`` or ``.png``) at its true physical size:
    the PDF's page is the paper (points = pixels / dpi * 72), the PNG carries ``dpi``. Written
    atomically: on a failure the file is as it was."""
    from svbrdf_render.plumbing import atomic_output

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".pdf", ".png"):
        given = repr(suffix) if suffix else "a name without suffix"
        raise DataError(f"{path}: the frame is written as .pdf or .png, not {given}")
    if path.is_dir():
        raise DataError(f"{path}: is a folder; give a file name ending in .pdf or .png")
    image = draw_frame(layout, dpi)
    with atomic_output(path) as tmp:
        if suffix == ".pdf":  # bilevel: CCITT G4, exact edges, no JPEG ringing around the markers
            Image = _pil()[0]
            bilevel = image.point(lambda v: 255 if v >= 128 else 0).convert("1", dither=Image.Dither.NONE)
            bilevel.save(tmp, format="PDF", resolution=float(dpi))
        else:
            image.save(tmp, format="PNG", dpi=(dpi, dpi))
    return path
