"""Capture: from a real flash photo to maps a material artist can use.

The pieces of ``svbrdf-models predict`` (and ``svbrdf-train predict``), each usable alone::

    photo, notes = load_photo("shot.jpg")              # EXIF-oriented, centre square, linear
    svbrdf = model.predict(photo)                       # maps at the model's resolution
    svbrdf = model.predict(photo, refine=100)           # refined at the square's own resolution
    svbrdf = tile_predict(model.predict, photo, model.resolution)  # or tiles at full size
    fit = flash_consistency(svbrdf, photo)              # re-render under the fitted flash
    entry = capture_one(model, "shot.jpg", "maps/shot", CaptureOptions(refine=100))  # all, written

It needs svbrdf-render and this package only (Pillow through ``svbrdf-models[photo]``, which is
``svbrdf-render[io]``): no training code, no tracking.

Photos are judged before any pixel is decoded where the file header allows it. Refused, with a
:class:`PhotoError` naming the file and what to do: a missing file or a folder, a file that is no
image, an image that is neither JPEG nor PNG, fewer than :data:`MIN_SIDE` pixels on the short side
(or a crop that small), more than :data:`MAX_PIXELS` pixels, a grey image (the albedo's colour cannot
be recovered from it), a translucent alpha channel, a crop that does not fit in the photo; with
refinement, maps asked smaller than :data:`svbrdf_render.MIN_REFINE_SIDE`.
Processed with a note: an EXIF orientation (applied), a 16-bit PNG (read at full precision), an
opaque alpha channel (dropped), a palette or CMYK image (converted), RGB channels that are all
equal (a grey picture saved as RGB), many clipped pixels, a black square (nothing lit: the maps
are guesses and a re-rendering RMSE near 0 says nothing), a square smaller than the model's
resolution (upsampled).

A tiled capture (``--tiles``) holds about :data:`TILED_BYTES_PER_PIXEL` bytes per pixel of its
maps: :func:`check_tiled_memory` refuses, before any work, a size this machine's available
memory cannot hold.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import struct
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import (
    DES18_DISTANCE,
    DES18_EFFECTS,
    MAP_NAMES,
    MIN_REFINE_SIDE,
    SVBRDF,
    Camera,
    FlashFit,
    MapFileError,
    PointLight,
    Refinement,
    Scene,
    fit_flash,
    linear_to_srgb,
    read_image,
    render,
    safe_normalize,
    srgb_to_linear,
)
from svbrdf_render.files import write_text

from .errors import DataError
from .figures import HEAT_MAX, error_heatmap, image_grid
from .material import to_directx
from .modelfile import square_photo
from .photos import exif_orientation, orient
from .refining import BACKEND, check_refine, pick_backend, refine_prediction, rerender, rerender_rmse

__all__ = [
    "ALBEDO_ENCODINGS",
    "CaptureOptions",
    "FLASH_FIT",
    "HEAT_MAX",
    "MAX_PIXELS",
    "MIN_SIDE",
    "MIN_TILEABLE_PHOTO",
    "NORMAL_ALIASES",
    "NORMAL_CONVENTIONS",
    "PhotoError",
    "RELIT_FORMATS",
    "capture_one",
    "available_memory",
    "check_tiled_memory",
    "tiled_capture_bytes",
    "error_heatmap",
    "flash_consistency",
    "load_photo",
    "orient",
    "relight_frames",
    "square",
    "tile_count",
    "tile_predict",
    "to_directx",
    "write_summary",
]

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
#: Peak memory of a tiled capture per pixel of its maps: the photo at that size, the blended maps
#: and their weights, the flash fit's re-renderings and gradients, the figures and the files'
#: buffers (about 70 float32 values). Measured as capture_one's peak resident memory with
#: --tiles: 4.1 GiB above the program at 4096 px (263 bytes per pixel), 240-270 bytes per pixel
#: added from 512 to 4096 px; so 8192 px maps need about 18 GiB.
TILED_BYTES_PER_PIXEL = 280
#: ... and beyond the per-pixel part, whatever the size (measured: about 270 MiB at 512 px).
TILED_FIXED_BYTES = 320 * 2**20
#: ``--normal-convention`` values: OpenGL (y up, the project's own) or DirectX (y down).
NORMAL_CONVENTIONS = ("opengl", "directx")
#: The smallest square (photo pixels) ``--tileable`` takes: the blend bands of
#: :func:`svbrdf_render.make_tileable` cover a quarter of the side at each border, and the part
#: they leave as it was must itself hold MIN_TILEABLE_SIDE (64) pixels of real detail.
MIN_TILEABLE_PHOTO = 128

#: Short names of the normal conventions.
NORMAL_ALIASES = {"gl": "opengl", "dx": "directx"}
#: ``--relit`` values: an animated GIF, a PNG grid of the frames, or no preview.
RELIT_FORMATS = ("gif", "png", "none")
#: How diffuse.png and specular.png store the albedos: linear (Des18) or sRGB (texture tools).
ALBEDO_ENCODINGS = ("linear", "srgb")
#: Frames of the relit preview, and the largest side it is rendered at.
RELIT_FRAMES = 24
RELIT_SIZE = 256
#: How :func:`flash_consistency` fits the flash (:func:`svbrdf_render.fit_flash` options). 60
#: steps at twice fit_flash's step size: on the 21 real-dev photos the RMSE is within 0.0005
#: of 150 steps at 0.05 on 20 of them and lower on the last (a local minimum escaped), in a
#: third of the time.
FLASH_FIT = {"steps": 60, "lr": 0.1, "fit_size": 128}

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_GREY_MODES = ("1", "L", "LA", "La", "I", "I;16", "I;16B", "I;16L", "I;16N", "F")


class PhotoError(DataError):
    """A photo that cannot be captured: names the file, what is wrong, and what to do."""

    def __init__(self, path, problem: str, hint: str = ""):
        self.path = str(path)
        self.problem = problem
        self.hint = hint
        super().__init__(f"{self.path}: {problem}" + (f"; {hint}" if hint else ""))


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


def load_photo(
    path, *, linear: bool = False, crop: tuple[int, int, int] | None = None
) -> tuple[Tensor, list[str]]:
    """Read a flash photo: ``(3, S, S)`` linear float32, the square to capture, and notes.

    The EXIF orientation is applied; ``crop = (x, y, size)`` in pixels of the oriented photo picks
    the square, else the largest centred one; values are decoded from sRGB unless ``linear``.
    Refused photos raise :class:`PhotoError` (see the module's docstring for which).
    """
    path = Path(path)
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
    image = square(orient(image, orientation), crop, path=path)
    clipped = float((image.amin(0) >= 254 / 255).float().mean())  # blown out to white
    if clipped > CLIPPED_SHARE:
        notes.append(f"{clipped:.0%} of the square is clipped (overexposed): expose for the highlight")
    if float(image.max()) < BLACK_LEVEL:
        notes.append(
            "the square is black (no value above 1/255): nothing lit to recover, so the maps are "
            "guesses and a re-rendering RMSE near 0 says nothing; check the exposure and the flash"
        )
    return (image if linear else srgb_to_linear(image)), notes


# -- predicting --------------------------------------------------------------------------------


def _positions(length: int, tile: int, stride: int) -> list[int]:
    if length <= tile:
        return [0]
    n = math.ceil((length - tile) / stride) + 1
    return sorted({round(i * (length - tile) / (n - 1)) for i in range(n)})


def _window(tile: int) -> Tensor:
    """Raised cosine (Hann) that never reaches 0: ``sin^2(pi (i + 1/2) / tile)``; with 50% overlap
    neighbouring windows sum to exactly 1."""
    i = torch.arange(tile, dtype=torch.float64)
    return torch.sin(math.pi * (i + 0.5) / tile).square().float()


def tile_predict(
    predict_fn: Callable[[Tensor], SVBRDF], photo: Tensor, tile: int, overlap: float = 0.5, *, batch: int = 8
) -> SVBRDF:
    """Maps of a photo larger than the model's input, from overlapping tiles blended without seams.

    Args:
        predict_fn: ``(N, 3, tile, tile)`` linear photos -> SVBRDF of N materials of that size.
        photo: ``(3, H, W)`` linear, ``H, W >= tile``.
        tile: side of a tile (the model's resolution).
        overlap: share of a tile its neighbour covers (0.5: half).
        batch: tiles per call of ``predict_fn``.

    Tiles start at evenly spread positions that end flush with the borders; each tile's maps are
    weighted by a separable raised-cosine window, summed, and divided by the sum of the weights,
    so the result is a smooth partition of unity. Normals are re-normalised after blending;
    the other maps are clamped to [0, 1]. Returns a batch of one at ``H x W``.
    """
    _, h, w = photo.shape
    if h < tile or w < tile:
        raise DataError(f"tile_predict: the photo is {w}x{h}, smaller than a tile ({tile})")
    if not 0 <= overlap < 1:
        raise DataError(f"tile_predict: overlap must be in [0, 1), got {overlap}")
    stride = max(1, round(tile * (1 - overlap)))
    corners = [(y, x) for y in _positions(h, tile, stride) for x in _positions(w, tile, stride)]
    win = _window(tile)
    weight = (win[:, None] * win[None, :])[None]  # (1, tile, tile)
    acc = torch.zeros(10, h, w)
    total = torch.zeros(1, h, w)
    for start in range(0, len(corners), batch):
        chunk = corners[start : start + batch]
        x = torch.stack([photo[:, y : y + tile, x : x + tile] for y, x in chunk])
        maps = predict_fn(x)
        packed = torch.cat([maps.normal, maps.diffuse, maps.roughness, maps.specular], 1).float().cpu()
        for k, (y, x) in enumerate(chunk):
            acc[:, y : y + tile, x : x + tile] += packed[k] * weight
            total[:, y : y + tile, x : x + tile] += weight
    out = (acc / total)[None]
    return SVBRDF(
        safe_normalize(out[:, 0:3], dim=1),
        out[:, 3:6].clamp(0, 1),
        out[:, 6:7].clamp(0, 1),
        out[:, 7:10].clamp(0, 1),
        validate=False,
    )


def tile_count(size: int, tile: int, overlap: float = 0.5) -> int:
    """How many tiles :func:`tile_predict` runs on a ``size x size`` photo."""
    return len(_positions(size, tile, max(1, round(tile * (1 - overlap))))) ** 2


def tiled_capture_bytes(size: int) -> int:
    """About how much memory a tiled capture of ``size x size`` maps takes at its peak, beyond
    the program and the model (see :data:`TILED_BYTES_PER_PIXEL`)."""
    return TILED_BYTES_PER_PIXEL * size * size + TILED_FIXED_BYTES


def available_memory() -> int | None:
    """Bytes of memory this process may still take: the kernel's ``MemAvailable`` (what can be
    had without swapping), lowered to a cgroup's limit when the process runs under one; None
    where neither can be read."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError, IndexError):
        pass
    if not found:
        try:
            found.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError, AttributeError):
            pass
    try:  # cgroup v2: the limit minus what the group uses
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit.isdigit():
            used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
            found.append(max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    return min(found) if found else None


def check_tiled_memory(size: int, what: str) -> None:
    """Refuse (:class:`DataError`, one line starting with ``what``) a tiled capture of ``size x
    size`` maps that needs more memory than :func:`available_memory` says there is; a tiled
    capture past it would be killed by the system, or swap for hours, after minutes of work."""
    need, have = tiled_capture_bytes(size), available_memory()
    if have is None or need <= have:
        return
    largest = math.isqrt(max(0, have - TILED_FIXED_BYTES) // TILED_BYTES_PER_PIXEL)
    raise DataError(
        f"{what}: a tiled capture of {size}x{size} maps needs about {need / 2**30:.1f} GiB of memory, "
        f"but {have / 2**30:.1f} GiB are available; give a --map-size of at most {largest} px, or "
        "free memory"
    )


# -- judging and showing -------------------------------------------------------------------------


def flash_consistency(svbrdf: SVBRDF, photo: Tensor, **fit_options) -> FlashFit:
    """Fit a flash so that the maps re-render the photo (:func:`svbrdf_render.fit_flash`).

    ``photo`` is ``(3, H, W)`` or ``(1, 3, H, W)`` linear, resampled (area) to the maps' size if it
    differs. ``FlashFit.rmse`` is the self-consistency figure: how well the maps explain the photo.
    ``fit_options`` override :data:`FLASH_FIT`.
    """
    if photo.dim() == 3:
        photo = photo[None]
    photo = photo.float()
    if tuple(photo.shape[-2:]) != tuple(svbrdf.size):
        photo = F.interpolate(photo, size=tuple(svbrdf.size), mode="area")
    with torch.inference_mode(False), torch.enable_grad():
        return fit_flash(svbrdf.detach().to(torch.float32), photo, **{**FLASH_FIT, **fit_options})


def _relight_raw(svbrdf: SVBRDF, n: int, radius: float, height: float) -> Tensor:
    """``(n, 3, H, W)`` linear renderings of the first material under a point light circling it
    at intensity 1, not clipped."""
    angles = torch.arange(n, dtype=torch.float32) * (2 * math.pi / n)
    pos = torch.stack([radius * angles.cos(), radius * angles.sin(), torch.full_like(angles, height)], -1)
    maps = svbrdf[0].detach().to(torch.float32)
    scene = Scene(Camera(torch.tensor([0.0, 0.0, DES18_DISTANCE])), (PointLight(pos, 1.0),), DES18_EFFECTS)
    return render(maps, scene)[0]  # (n, 3, H, W)


def _expose(frames: Tensor, intensity=None) -> Tensor:
    """Frames scaled by ``intensity`` (None: so that their brightest 1% just reaches 0.9),
    clipped to [0, 1]."""
    if intensity is None:
        sample = frames.flatten()[:: max(1, frames.numel() // 1_000_000)]
        top = float(torch.quantile(sample, 0.99))
        intensity = 0.9 / top if top > 0 else 1.0
    return (frames * float(intensity)).nan_to_num(0.0).clamp(0, 1)


def relight_frames(
    svbrdf: SVBRDF, n: int = RELIT_FRAMES, *, radius: float = 1.5, height: float = 1.6, intensity=None
) -> Tensor:
    """``(n, 3, H, W)`` linear renderings of the first material under a point light circling it.

    The camera stays on the axis at the Des18 distance; the light goes round at ``radius`` from the
    axis and ``height`` above the patch. ``intensity=None`` exposes all frames alike so that their
    brightest 1% just reaches 0.9; values are clipped to [0, 1].
    """
    return _expose(_relight_raw(svbrdf, n, radius, height), intensity)


def _relit_versions(versions: list[SVBRDF]) -> Tensor:
    """``(V, RELIT_FRAMES, 3, S, S)``: the relit frames of each version, at the last version's size
    (at most :data:`RELIT_SIZE`), all exposed alike."""
    side = min(RELIT_SIZE, max(versions[-1].size))
    raw = [_relight_raw(v if tuple(v.size) == (side, side) else v.resize(side), RELIT_FRAMES, 1.5, 1.6)
           for v in versions]  # fmt: skip
    return _expose(torch.stack(raw))


def _relit_grid(frames: Tensor, names: list[str] | None = None, cols: int = 6) -> Tensor:
    """The relit frames ``(V, n, 3, H, W)`` as a grid: rows of ``cols`` frames; with several
    versions (``names``), one row per version for each group of angles."""
    n = frames.shape[1]
    names = names or [""]
    rows, labels = [], []
    for i in range(0, n, cols):
        for v, name in enumerate(names):
            rows.append(list(linear_to_srgb(frames[v, i : i + cols])))
            labels.append(f"{name} {i * 360 // n}°".strip())
    return image_grid(rows, [f"+{k * 360 // n}°" for k in range(cols)], labels)


def _resample(photo: Tensor, size: int) -> Tensor:
    if photo.shape[-1] == size:
        return photo
    return F.interpolate(
        photo[None], size=(size, size), mode="bilinear", align_corners=False, antialias=True
    )[0]


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


# -- one photo, end to end -----------------------------------------------------------------------


@dataclass(frozen=True)
class CaptureOptions:
    """How :func:`capture_one` reads a photo and what it writes.

    Attributes:
        linear: the file holds linear values (default: sRGB-encoded, as cameras save).
        crop: ``(x, y, size)`` in pixels of the oriented photo, or None for the centred square.
        tiles: predict at high resolution from overlapping tiles of the model's resolution.
        map_size: with ``tiles`` or ``refine``, the side of the maps (default: the square's own).
        bits: 8 or 16, the maps' and input.png's PNG depth.
        normal_convention: ``"opengl"`` or ``"directx"`` (green channel flipped); ``"gl"`` and
            ``"dx"`` are read as those.
        relit: ``"gif"``, ``"png"`` or ``"none"``.
        albedo_encoding: how diffuse.png and specular.png store values: ``"srgb"`` (default,
            what colour inputs of texture tools such as Blender and Substance expect) or
            ``"linear"`` (Des18's convention, for research). basecolor.png is always sRGB.
        exr: also write the maps as OpenEXR (linear half floats).
        tileable: make the maps' opposite edges match (:func:`svbrdf_render.tiling.make_tileable`).
        refine: refinement steps after the network (0: the network's maps only).
        refine_seconds: with ``refine``, stop refining a photo after this many seconds.
        scene: with ``refine``, the capture's scene (default: the flash found from the maps).
        backend: with ``refine``, the renderer's backend (``"auto"``, ``"eager"`` or ``"compiled"``).
    """

    linear: bool = False
    crop: tuple[int, int, int] | None = None
    tiles: bool = False
    map_size: int | None = None
    bits: int = 8
    normal_convention: str = "opengl"
    relit: str = "gif"
    albedo_encoding: str = "srgb"
    exr: bool = False
    tileable: bool = False
    refine: int = 0
    refine_seconds: float | None = None
    scene: Scene | None = None
    backend: str = BACKEND

    def __post_init__(self):
        convention = NORMAL_ALIASES.get(self.normal_convention, self.normal_convention)
        object.__setattr__(self, "normal_convention", convention)
        if self.albedo_encoding not in ALBEDO_ENCODINGS:
            raise DataError(
                f"albedo encoding must be one of {ALBEDO_ENCODINGS}, got {self.albedo_encoding!r}"
            )
        if self.normal_convention not in NORMAL_CONVENTIONS:
            raise DataError(
                f"normal convention must be one of {NORMAL_CONVENTIONS}, got {self.normal_convention!r}"
            )
        if self.relit not in RELIT_FORMATS:
            raise DataError(f"relit preview must be one of {RELIT_FORMATS}, got {self.relit!r}")
        if self.bits not in (8, 16):
            raise DataError(f"bits must be 8 or 16, got {self.bits}")
        if self.exr and importlib.util.find_spec("OpenEXR") is None:
            raise DataError("--exr needs the OpenEXR package: pip install 'svbrdf-render[exr]'")
        self._check_refine()

    def _check_refine(self) -> None:
        check_refine(self.refine, self.refine_seconds)
        if self.map_size is not None and not (self.tiles or self.refine):
            raise DataError("map size is for tiled or refined capture: give tiles=True (--tiles) with it")
        if self.refine and self.map_size is not None and self.map_size < MIN_REFINE_SIDE:
            raise DataError(
                f"map size (--map-size) {self.map_size} is smaller than {MIN_REFINE_SIDE} px: too few "
                "pixels to refine"
            )
        if not self.refine and (self.refine_seconds is not None or self.scene is not None):
            raise DataError(
                "refine seconds and scene (--refine-seconds, --scene) are for refined capture: give "
                "refine > 0 (--refine STEPS) with them"
            )


@dataclass(frozen=True)
class _Judged:
    """What a capture shows and records: the maps to write, the figures and the entry's figures."""

    svbrdf: SVBRDF
    figure: Tensor
    frames: Tensor | None  # (V, n, 3, H, W): one set of relit frames per version
    versions: list[str]
    entry: dict


def capture_one(predictor, path, out_dir, options: CaptureOptions | None = None, *, progress=None) -> dict:
    """Capture one photo into the material folder ``out_dir``; returns its summary entry
    (``status`` ``"ok"``).

    ``predictor`` has ``resolution`` and ``predict(photo)`` (a :class:`~svbrdf_models.TrainedModel`,
    or svbrdf-train's ``Predictor``; its ``predict_batch(photos)`` is used for tiles when it has
    one). Writes the maps (metal/rough and the project's own), material.json, material.gltf,
    material.mtlx, index.html, input.png (the square the maps are of, sRGB), rerender.png (photo
    | re-rendering | error heat map; with refinement the network's and the refined maps side by
    side) and relit.gif or relit.png: see :mod:`svbrdf_models.material`. ``progress(step, total,
    loss)`` follows the refinement. A photo that cannot be used, or a folder that holds another
    material, raises before any work; an interrupt or an error leaves ``out_dir`` as it was (the
    folder is staged and moved in whole).
    """
    from .material import MaterialContent, check_material_folder, write_material

    options = options or CaptureOptions()
    path, out_dir = Path(path), Path(out_dir)
    check_material_folder(out_dir, path)
    photo, notes = load_photo(path, linear=options.linear, crop=options.crop)
    side = photo.shape[-1]
    if options.tileable and side < MIN_TILEABLE_PHOTO:
        raise PhotoError(
            path,
            f"the square is {side} px; --tileable needs at least {MIN_TILEABLE_PHOTO} px of photo",
            "give a larger photo or --crop, or leave out --tileable",
        )
    photo, svbrdf, tiles = _predict_square(predictor, photo, options, notes, path)
    if options.refine:  # on the model's device, where the network ran
        device = getattr(predictor, "device", torch.device("cpu"))
        judged = _judge_refined(photo, svbrdf, options, progress, device)
    else:
        judged = _judge_network(photo, svbrdf, options)
    svbrdf, frames, tileable = judged.svbrdf, judged.frames, None
    if options.tileable:
        svbrdf, tileable = _tileable(svbrdf)
        if options.relit != "none":  # the preview shows the maps written
            frames = torch.cat([frames[:-1], _relit_versions([svbrdf])])
    relit = None
    if options.relit == "png":
        relit = _relit_grid(frames, judged.versions if len(judged.versions) > 1 else None)
    elif options.relit == "gif":
        relit = frames[-1]
    entry = {
        "photo": str(path),
        "folder": str(out_dir),
        "status": "ok",
        "notes": notes,
        "square": side,
        "maps": int(svbrdf.size[0]),
        "tiles": tiles,
        **judged.entry,
        "tileable": tileable,
    }
    record = _material_record(predictor, path, options, entry)
    write_material(out_dir, svbrdf, MaterialContent(photo, judged.figure, relit, record), options)
    return entry


def _tileable(svbrdf: SVBRDF) -> tuple[SVBRDF, dict]:
    """The maps made tileable, and their seam errors before and after (median over channels)."""
    from svbrdf_render.tiling import make_tileable, seam_error

    def seams(m: SVBRDF) -> dict:
        return {name: round(float(seam_error(getattr(m, name))[0]), 3) for name in MAP_NAMES}

    before = seams(svbrdf)
    tiled = make_tileable(svbrdf)
    return tiled, {"seam_error_before": before, "seam_error_after": seams(tiled)}


def _material_record(predictor, path: Path, options: CaptureOptions, entry: dict) -> dict:
    """material.json's fields that the capture knows: photo, model, refinement, provenance."""
    from .material import photo_sha256, provenance

    model = {key: getattr(predictor, key, None) for key in ("source", "sha256", "resolution")}
    model["steps"] = getattr(predictor, "steps", getattr(predictor, "step", None))
    return {
        "name": path.stem,
        "photo": {"file": path.name, "sha256": photo_sha256(path), "square": entry["square"],
                  "crop": list(options.crop) if options.crop else None,
                  "encoding": "linear" if options.linear else "srgb"},  # fmt: skip
        "model": {k: (str(v) if k == "source" and v is not None else v) for k, v in model.items()},
        "maps_size": entry["maps"],
        "tiles": entry["tiles"],
        "rerender_rmse": entry["rmse"],
        "flash": entry["flash"],
        "refine": entry["refine"] or {"budget": 0},
        "tileable": entry["tileable"],
        "provenance": provenance(),
    }


def _judge_network(photo: Tensor, svbrdf: SVBRDF, options: CaptureOptions) -> _Judged:
    """The network's maps judged under the flash fitted to them."""
    fit = flash_consistency(svbrdf, photo)
    rmse = float(fit.rmse[0])
    figure = _rerender_figure(photo, [fit.rendering[0]], [rmse], ["re-rendering"])
    frames = _relit_versions([svbrdf]) if options.relit != "none" else None
    entry = {
        "rmse": _finite(rmse),
        "flash": {
            "position": [_finite(v) for v in fit.position[0].tolist()],
            "intensity": _finite(fit.intensity[0]),
        },
        "refine": None,
    }
    return _Judged(svbrdf, figure, frames, ["network"], entry)


def _judge_refined(photo: Tensor, network: SVBRDF, options: CaptureOptions, progress, device) -> _Judged:
    """The network's maps refined against ``photo`` on ``device``; both judged under the
    refinement's scene."""
    result: Refinement = refine_prediction(
        photo[None],
        network.to(device),
        options.refine,
        seconds=options.refine_seconds,
        scene=options.scene,
        callback=progress,
        backend=options.backend,
    )
    size = tuple(photo.shape[-2:])
    renderings = [rerender(network, result.scene, size)[0], rerender(result.svbrdf, result.scene)[0]]
    rmse = [float(rerender_rmse(r[None], photo)[0]) for r in renderings]
    versions = ["network", "refined"]
    figure = _rerender_figure(photo, renderings, rmse, versions)
    frames = _relit_versions([network, result.svbrdf]) if options.relit != "none" else None
    light = result.scene.point_lights[0]
    entry = {
        "rmse": _finite(rmse[1]),
        "flash": {
            "position": [_finite(v) for v in light.position.reshape(-1, 3)[0].tolist()],
            "intensity": _finite(light.intensity.reshape(-1)[0]),
        },
        "refine": {
            "budget": options.refine,
            "seconds_budget": options.refine_seconds,
            "steps": int(result.steps),
            "seconds": round(float(result.seconds), 3),
            "backend": pick_backend(options.backend, *size),
            "rmse_network": _finite(rmse[0]),
            "rmse_refined": _finite(rmse[1]),
        },
    }
    return _Judged(result.svbrdf, figure, frames, versions, entry)


def _predict_square(predictor, photo: Tensor, options: CaptureOptions, notes: list[str], path):
    """The photo's square brought to the size the maps are made at, the network's maps, and the
    tiles used (0: not tiled; 1: one tile). A square smaller than the model's resolution is
    noted (upsampled). With refinement the maps are made at ``map_size`` or the square's side."""
    res = int(predictor.resolution)
    side = photo.shape[-1]
    if not options.tiles:
        if side < res:
            soft = "the network sees it softened" if options.refine else "the maps will be soft"
            notes.append(f"the square ({side} px) is upsampled to the model's {res} px: {soft}")
        svbrdf = predictor.predict(_resample(photo, res))
        size = (options.map_size or side) if options.refine else res
        _check_refine_size(size, options, path)
        return _resample(photo, size), svbrdf, 0
    size = options.map_size or side
    if size < res:
        notes.append(f"the square ({size} px) is smaller than a tile ({res} px): predicted as one tile")
        size = res
    check_tiled_memory(size, f"{path}: --tiles")
    photo = _resample(photo, size)
    tiles = tile_count(size, res)
    batch_fn = getattr(predictor, "predict_batch", predictor.predict)
    svbrdf = tile_predict(batch_fn, photo, res) if tiles > 1 else predictor.predict(photo)
    return photo, svbrdf, tiles


def _check_refine_size(size: int, options: CaptureOptions, path) -> None:
    if options.refine and size < MIN_REFINE_SIDE:
        raise PhotoError(
            path,
            f"the maps would be {size} px, smaller than {MIN_REFINE_SIDE}: too few pixels to refine",
            "give a larger photo or --map-size, or --refine 0",
        )


def _rerender_figure(photo: Tensor, renderings: list[Tensor], rmse: list[float], names: list[str]) -> Tensor:
    """rerender.png: the photo, its re-rendering by each version of the maps, and their error
    heat maps; the row's label gives the RMSE of each (network first)."""
    shown = [linear_to_srgb(photo), *(linear_to_srgb(r) for r in renderings)]
    shown += [error_heatmap(photo, r) for r in renderings]
    scale = f"|error| 0-{HEAT_MAX:g}"
    if len(names) == 1:
        columns = ["photo", names[0], scale]
    else:
        columns = ["photo", *(f"{n} re-rendering" for n in names), *(f"{n} {scale}" for n in names)]
    label = "RMSE " + " -> ".join(f"{r:.4f}" for r in rmse)
    return image_grid([shown], columns, [label])


def write_summary(path, entries: list[dict], **extra) -> dict:
    """``summary.json``: the entries, the median RMSE over the photos captured, and ``extra``."""
    import statistics

    values = [e["rmse"] for e in entries if e.get("status") == "ok" and e.get("rmse") is not None]
    summary = {
        **extra,
        "photos": len(entries),
        "captured": sum(e.get("status") == "ok" for e in entries),
        "failed": sum(e.get("status") != "ok" for e in entries),
        "median_rmse": statistics.median(values) if values else None,
        "entries": entries,
    }
    write_text(path, json.dumps(summary, indent=2) + "\n")  # atomic: never a 0-byte summary
    return summary
