"""Flash photos as they are shown, and judged before they are used.

:func:`load_photo` reads a photo for the photo tool (:mod:`svbrdf_models.capture.one`): the EXIF
orientation a camera records applied to the pixels (:func:`orient`, also used by svbrdf-train's
photo folders), the square to capture (:func:`square`), values linear. Pillow (svbrdf-render's
``io`` extra, or this package's ``photo`` extra) reads the header and the tag; the pixels are
turned with torch alone.

Photos are judged before any pixel is decoded where the file header allows it. Refused, with a
:class:`PhotoError` naming the file and what to do: a missing file or a folder, a file that is no
image, an image that is neither JPEG nor PNG, fewer than :data:`MIN_SIDE` pixels on the short side
(or a crop that small), more than :data:`MAX_PIXELS` pixels, a grey image (the albedo's colour
cannot be recovered from it), a translucent alpha channel, an animated PNG (which frame is the
photo?), a crop that does not fit in the photo.
Read with a note: an EXIF orientation (applied), a 16-bit PNG (read at full precision), an opaque
alpha channel (dropped), a palette or CMYK image (converted), RGB channels that are all equal (a
grey picture saved as RGB), many clipped pixels, a black square (nothing lit), a PNG tagged
linear (a gAMA chunk of 1.0 and no sRGB chunk or ICC profile: decoded as linear values, as the
tag says, though ``linear`` was not given: :func:`tagged_linear`).
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import MapFileError, read_image, read_png_encoding, srgb_to_linear

from ..errors import DataError

__all__ = [
    "EXIF_ORIENTATION",
    "MAX_PIXELS",
    "MIN_SIDE",
    "PhotoError",
    "exif_orientation",
    "file_orientation",
    "load_photo",
    "orient",
    "photo_encoding",
    "read_oriented",
    "square",
    "square_box",
    "square_photo",
    "square_side",
    "tagged_linear",
]

#: The EXIF tag saying how to turn the stored pixels to show the photo upright (1-8).
EXIF_ORIENTATION = 0x0112
#: Photos (and crops) with a shorter side below this many pixels are refused: too little to see.
MIN_SIDE = 64
#: Photos with more pixels than this are refused before decoding (50 megapixels).
MAX_PIXELS = 50_000_000
#: Image formats read (as Pillow names them; MPO is the JPEG some phones save).
PHOTO_FORMATS = ("JPEG", "MPO", "PNG")
#: Share of blown-out pixels (every channel at the top) above which a note warns of overexposure.
CLIPPED_SHARE = 0.02
#: A square whose brightest value (as stored in the file, 0-1) is below this is black: noted.
BLACK_LEVEL = 1.5 / 255

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_GREY_MODES = ("1", "L", "LA", "La", "I", "I;16", "I;16B", "I;16L", "I;16N", "F")


class PhotoError(DataError):
    """A photo that cannot be captured: names the file, what is wrong, and what to do."""

    def __init__(self, path, problem: str, hint: str = ""):
        self.path = str(path)
        self.problem = problem
        self.hint = hint
        super().__init__(f"{self.path}: {problem}" + (f"; {hint}" if hint else ""))


def square_photo(photo: Tensor, size: int | None) -> Tensor:
    """Centre-crop ``(C, H, W)`` to its shorter side, then resample to ``size`` if given.

    Resampling is bilinear with antialiasing (a triangle filter: no overshoot, so values stay
    in range) and happens on linear values, where averaging is physically meaningful.
    """
    _, h, w = photo.shape
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    photo = photo[:, top : top + s, left : left + s]
    if size is not None and s != size:
        photo = F.interpolate(
            photo[None], size=(size, size), mode="bilinear", align_corners=False, antialias=True
        )[0]
    return photo.contiguous()


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


# -- reading ---------------------------------------------------------------------------------


def square(photo: Tensor, crop: tuple[int, int, int] | None = None, *, path=None) -> Tensor:
    """The square of ``(C, H, W)`` to capture: ``crop = (x, y, size)`` (left column, top row, side,
    in pixels), or the largest centred square when ``crop`` is None. A crop that does not fit, or
    is smaller than :data:`MIN_SIDE`, is a :class:`PhotoError` (naming ``path`` when given)."""
    if crop is None:
        return square_photo(photo, None)
    x, y, size = (int(v) for v in crop)
    _, h, w = photo.shape
    where = path if path is not None else "photo"
    if size < MIN_SIDE:
        raise PhotoError(
            where, f"the crop is {size} px, smaller than {MIN_SIDE}", "give a larger --crop SIZE"
        )
    if x < 0 or y < 0 or x + size > w or y + size > h:
        raise PhotoError(
            where,
            f"the crop {x},{y},{size} does not fit in the {w}x{h} photo (as displayed, after EXIF "
            "orientation)",
            f"give --crop X,Y,SIZE with X+SIZE <= {w} and Y+SIZE <= {h}",
        )
    return photo[:, y : y + size, x : x + size].contiguous()


def _png_bit_depth(path: Path) -> int | None:
    with open(path, "rb") as f:
        head = f.read(26)
    if len(head) < 26 or not head.startswith(_PNG_MAGIC) or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">B", head[24:25])[0]


def _inspect(path: Path, notes: list[str]) -> int:
    """Judge the file from its header (and alpha); returns its EXIF orientation."""
    with _open_image(path) as im:
        fmt, mode = im.format, im.mode
        _check_header(path, im)
        _check_alpha(path, im, notes)
        if mode == "P":
            notes.append("palette image (at most 256 colours) converted to RGB: expect banding")
        elif mode == "CMYK":
            notes.append("CMYK image converted to RGB")
        orientation, orientation_note = exif_orientation(im)
    if fmt == "PNG" and _png_bit_depth(path) == 16:
        notes.append("16-bit PNG read at full precision")
    if orientation_note:
        notes.append(orientation_note)
    return orientation


def square_box(path, crop: tuple[int, int, int] | None = None) -> tuple[int, int, int, int, int]:
    """``(x, y, side, width, height)``: where the square a capture of ``path`` takes lies in the
    photo as displayed (after its EXIF orientation), and the photo's size; from the header."""
    with _open_image(Path(path)) as im:
        width, height = im.size
        orientation, _ = exif_orientation(im)
    if orientation in (5, 6, 7, 8):  # a quarter turn: the displayed photo is the other way round
        width, height = height, width
    if crop is not None:
        x, y, side = (int(v) for v in crop)
    else:
        side = min(width, height)
        x, y = (width - side) // 2, (height - side) // 2
    return x, y, side, width, height


def square_side(path, crop: tuple[int, int, int] | None = None) -> int | None:
    """The side of the square a capture of ``path`` takes (the crop's, or the shorter side of
    the photo), read from the file's header without decoding it; None when it cannot be read
    (the capture itself then says why)."""
    if crop is not None:
        return int(crop[2])
    try:
        with _open_image(Path(path)) as im:
            return min(im.size)
    except PhotoError:
        return None


def _open_image(path: Path):
    """The PIL image of ``path``, not yet decoded; a file that is no image is a :class:`PhotoError`."""
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            return Image.open(path)
    except Image.DecompressionBombError as e:
        raise PhotoError(
            path, f"is far too large ({e})", f"downscale it below {MAX_PIXELS / 1e6:.0f} megapixels"
        ) from None
    except Exception as e:  # UnidentifiedImageError, OSError, SyntaxError...
        raise PhotoError(
            path,
            f"cannot decode it as an image ({type(e).__name__})",
            "give a JPEG or PNG photo (convert HEIC or RAW files first)",
        ) from None


def _check_header(path: Path, im) -> None:
    """Refuse an image that is not a JPEG or PNG, too large, too small or grey."""
    fmt, mode, (w, h) = im.format, im.mode, im.size
    if fmt not in PHOTO_FORMATS:
        raise PhotoError(path, f"is a {fmt} image, not a JPEG or PNG", "convert it to PNG or JPEG")
    if fmt == "PNG" and getattr(im, "n_frames", 1) > 1:  # APNG; a phone's MPO JPEG holds 2 on purpose
        raise PhotoError(
            path,
            f"is an animated PNG ({im.n_frames} frames), not one photo",
            "save the frame to capture as a still PNG or JPEG",
        )
    if w * h > MAX_PIXELS:
        raise PhotoError(
            path,
            f"has {w}x{h} = {w * h / 1e6:.1f} megapixels, more than {MAX_PIXELS / 1e6:.0f}",
            "downscale it (the maps are made at a few hundred to a few thousand pixels)",
        )
    if min(w, h) < MIN_SIDE:
        raise PhotoError(
            path,
            f"is {w}x{h}, smaller than {MIN_SIDE} px on its short side",
            "take a larger photo (the material should fill a square of at least a few hundred pixels)",
        )
    if mode in _GREY_MODES or (mode == "P" and im.palette is not None and im.palette.mode == "L"):
        raise PhotoError(
            path,
            f"is a grey image (mode {mode})",
            "the diffuse colour cannot be recovered from it; give the photo in colour",
        )


def _check_alpha(path: Path, im, notes: list[str]) -> None:
    """Refuse a translucent alpha channel; note an opaque one (dropped)."""
    mode = im.mode
    if not (mode in ("RGBA", "RGBa", "PA") or (mode == "P" and "transparency" in im.info)):
        return
    try:
        lo, _ = im.convert("RGBA").getchannel("A").getextrema()
    except Exception as e:
        raise PhotoError(path, f"cannot decode it ({type(e).__name__}: {e})", "is it complete?") from None
    if lo < 255:
        raise PhotoError(
            path,
            f"has a translucent alpha channel (lowest alpha {lo}/255)",
            "a photo is opaque: export it without transparency (flattened)",
        )
    notes.append("opaque alpha channel dropped")


def read_oriented(path, *, linear: bool = False) -> tuple[Tensor, list[str]]:
    """The whole photo as it is shown, ``(3, H, W)`` linear float32 (its EXIF orientation
    applied; decoded from sRGB unless ``linear`` or :func:`tagged_linear`), and notes. Judged
    as :func:`load_photo` judges it (a :class:`PhotoError` when refused)."""
    image, notes = _oriented(Path(path))
    return _decoded(image, Path(path), linear, notes), notes


#: The note of a PNG read as linear because its header says so (:func:`tagged_linear`).
LINEAR_TAG_NOTE = (
    "the PNG is tagged linear (gAMA 1.0, no sRGB chunk or ICC profile): read as linear values, as "
    "the tag says; give --linear to say so yourself, or save it without the gAMA chunk if it is sRGB"
)


def tagged_linear(path) -> bool:
    """Whether ``path`` is a PNG whose header says its values are linear
    (:func:`svbrdf_render.read_png_encoding`: a cICP chunk of linear transfer, else a gAMA chunk
    of 1.0 with no sRGB chunk) and holds no ICC profile, which would say otherwise. Any other
    file (a JPEG, an untagged PNG, one tagged sRGB or gAMA 1/2.2) is not."""
    try:
        if read_png_encoding(path) != "linear":
            return False
        with _open_image(Path(path)) as im:
            return not im.info.get("icc_profile")
    except (OSError, PhotoError):
        return False


def photo_encoding(path, linear: bool) -> str:
    """How the capture decodes ``path``: ``"linear"`` when ``linear`` is given or the file is
    :func:`tagged_linear`, else ``"srgb"`` (material.json's ``photo.encoding``)."""
    return "linear" if linear or tagged_linear(path) else "srgb"


def _decoded(image: Tensor, path: Path, linear: bool, notes: list[str]) -> Tensor:
    """``image`` (values as stored, 0-1) as linear values: as they are with ``linear`` or a
    linear tag (noted), else decoded from sRGB."""
    if linear:
        return image
    if tagged_linear(path):
        notes.append(LINEAR_TAG_NOTE)
        return image
    return srgb_to_linear(image)


def _oriented(path: Path) -> tuple[Tensor, list[str]]:
    """The whole photo as stored in the file, its EXIF orientation applied, and notes."""
    if not path.exists():
        raise PhotoError(path, "no such file", "check the path")
    if not path.is_file():
        raise PhotoError(path, "is a folder, not a photo", "give the photo files (e.g. DIR/*.jpg)")
    notes: list[str] = []
    orientation = _inspect(path, notes)
    try:
        image = read_image(path, channels=3)
    except MapFileError as e:
        raise PhotoError(
            path, f"cannot decode it ({e.problem})", "is it a complete PNG or JPEG file?"
        ) from None
    if bool(
        ((image[0] - image[1]).abs().max() < 1.5 / 255) & ((image[1] - image[2]).abs().max() < 1.5 / 255)
    ):
        notes.append(
            "R, G and B are equal everywhere: a grey picture saved as colour? The diffuse will be grey"
        )
    return orient(image, orientation), notes


def load_photo(
    path, *, linear: bool = False, crop: tuple[int, int, int] | None = None
) -> tuple[Tensor, list[str]]:
    """Read a flash photo: ``(3, S, S)`` linear float32, the square to capture, and notes.

    The EXIF orientation is applied; ``crop = (x, y, size)`` in pixels of the oriented photo picks
    the square, else the largest centred one; values are decoded from sRGB unless ``linear``
    or the PNG is :func:`tagged_linear` (noted).
    Refused photos raise :class:`PhotoError` (see the module's docstring for which).
    """
    path = Path(path)
    image, notes = _oriented(path)
    image = square(image, crop, path=path)
    clipped = float((image.amin(0) >= 254 / 255).float().mean())  # blown out to white
    if clipped > CLIPPED_SHARE:
        notes.append(f"{clipped:.0%} of the square is clipped (overexposed): expose for the highlight")
    if float(image.max()) < BLACK_LEVEL:
        notes.append(
            "the square is black (no value above 1/255): nothing lit to recover, so the maps are "
            "guesses and a re-rendering RMSE near 0 says nothing; check the exposure and the flash"
        )
    return _decoded(image, path, linear, notes), notes
