"""Map files: the Deschaintre 2018 strip and folders of four PNG maps.

Needs the ``io`` extra (Pillow, pypng). Formats:

- **Des18 strip**: one image of five square tiles side by side,
  ``input | normal | diffuse | roughness | specular``; normal stored as ``(n + 1) / 2``,
  roughness grey in three channels, albedos linear as stored.
- **Map folder**: ``normal.png``, ``diffuse.png``, ``roughness.png``, ``specular.png``
  (``.jpg`` accepted when reading), same size, 8- or 16-bit.

Encodings inside the file: :func:`write_image` with ``encoding="srgb"`` or ``"linear"`` says
how the stored values are encoded in the PNG's colour chunks, so that viewers and texture
tools need not guess: ``cICP`` (primaries BT.709, transfer sRGB = 13 or linear = 8, full
range), with ``sRGB`` + ``gAMA`` 1/2.2 for sRGB and ``gAMA`` 1.0 for linear as the fallback
older decoders read. A ``tEXt`` ``Comment`` chunk can say what the image holds (a normal
map's convention, say). :func:`read_png_encoding` reads the tag back. OpenEXR files
(:func:`write_exr`, the ``exr`` extra: the Academy Software Foundation's ``OpenEXR``
bindings) are linear by definition. :func:`write_gif` writes frames as a looping GIF.

Handling of unusual files: 16-bit PNGs are read at full precision; an alpha channel
that is fully opaque is dropped; palette images are expanded; a grey image is accepted
where one channel is enough (roughness) or replicated for albedos, and refused for
normals and for the Des18 strip. Anything else (truncated, not an image, wrong tile
count, non-square tiles, translucent alpha) is a :class:`MapFileError` naming the file.
"""

from __future__ import annotations

import functools
import struct
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .._optional import require
from ..errors import MapFileError
from ..geometry import safe_normalize
from ..maps import MAP_NAMES, SVBRDF, decode_normal, encode_normal
from ..plumbing import atomic_output

__all__ = [
    "Des18Sample",
    "read_image",
    "write_image",
    "write_exr",
    "write_gif",
    "read_png_encoding",
    "ENCODINGS",
    "read_des18",
    "write_des18",
    "read_map_folder",
    "write_map_folder",
    "srgb_to_linear",
    "linear_to_srgb",
]

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_MAP_EXTENSIONS = (".png", ".jpg", ".jpeg")

#: How an image's stored values are encoded (the ``encoding`` of :func:`write_image`).
ENCODINGS = ("srgb", "linear")

# cICP: colour primaries 1 (BT.709, sRGB's), transfer 13 (sRGB) or 8 (linear), matrix 0 (RGB),
# full range. gAMA holds 100000 x the encoding exponent: 1/2.2 for sRGB (the value the PNG
# specification pairs with an sRGB chunk), 1.0 for linear.
_COLOUR_CHUNKS = {
    "srgb": ((b"cICP", bytes([1, 13, 0, 1])), (b"sRGB", b"\x00"), (b"gAMA", struct.pack(">I", 45455))),
    "linear": ((b"cICP", bytes([1, 8, 0, 1])), (b"gAMA", struct.pack(">I", 100000))),
}


@functools.cache
def _pil():
    """Pillow's Image module (the viewer's embedded maps use it too), found once."""
    return require("PIL.Image", "Pillow", "reading and writing images")


def _pypng():
    return require("png", "pypng", "16-bit PNG")


def srgb_to_linear(x: Tensor) -> Tensor:
    """The sRGB decoding curve (IEC 61966-2-1) on values in [0, 1]."""
    x = x.clamp(0, 1)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: Tensor) -> Tensor:
    """The sRGB encoding curve on values in [0, 1] (clamped before the power)."""
    x = x.clamp(0, 1)
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055)


def _png_header(path: Path) -> tuple[int, int] | None:
    """``(bit_depth, colour_type)`` of a PNG file, or None if it is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(29)
    if len(head) < 29 or not head.startswith(_PNG_MAGIC) or head[12:16] != b"IHDR":
        return None
    bit_depth, colour_type = struct.unpack(">BB", head[24:26])
    return bit_depth, colour_type


def _read_png16(path: Path) -> np.ndarray:
    png = _pypng()
    try:
        with open(path, "rb") as f:  # pypng leaves a file it opened itself unclosed
            w, h, rows, info = png.Reader(file=f).asDirect()
            planes = info["planes"]
            arr = np.vstack([np.asarray(row, dtype=np.uint16) for row in rows])
    except Exception as e:  # pypng raises several types for damaged files
        raise MapFileError(
            path, f"cannot decode this 16-bit PNG ({e})", "the file may be truncated"
        ) from None
    return arr.reshape(h, w, planes).astype(np.float32) / 65535.0


def _decode_pil(path: Path) -> np.ndarray:
    """An image other than a 16-bit PNG as ``(H, W, C)`` float32 in ``[0, 1]``, via Pillow."""
    Image = _pil()
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
                mode = im.mode
            if mode in ("I;16", "I;16B", "I"):
                return np.asarray(im, dtype=np.float32)[..., None] / 65535.0
            if mode in ("L", "LA", "RGB", "RGBA"):
                arr = np.asarray(im, dtype=np.float32) / 255.0
                return arr[..., None] if arr.ndim == 2 else arr
            if mode in ("1", "CMYK", "YCbCr", "F"):
                return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
            raise MapFileError(path, f"unsupported image mode {mode!r}", "save it as 8- or 16-bit RGB PNG")
    except MapFileError:
        raise
    except Exception as e:  # PIL raises UnidentifiedImageError, OSError, SyntaxError...
        raise MapFileError(
            path, f"cannot decode the image ({type(e).__name__}: {e})",
            "is it a complete PNG or JPEG file?",
        ) from None


def _colour_channels(path: Path, arr: np.ndarray) -> np.ndarray:
    """``arr`` ``(H, W, C)`` without its alpha channel, which must be opaque."""
    if arr.shape[2] not in (2, 4):
        return arr
    alpha = arr[..., -1]
    if float(alpha.min()) < 1.0:
        raise MapFileError(
            path,
            f"has a translucent alpha channel (min alpha {float(alpha.min()):.3f})",
            "maps must be opaque: flatten the image or drop the alpha channel",
        )
    return arr[..., :-1]


def read_image(path, *, channels: int | None = 3) -> Tensor:
    """Read an image as a float32 tensor ``(C, H, W)`` in ``[0, 1]``; values as stored.

    ``channels=3`` returns RGB (grey replicated, opaque alpha dropped); ``channels=1``
    returns one grey channel (an RGB image must then have equal channels); ``None`` keeps
    the file's colour channels (1 or 3). Translucent alpha is an error.
    """
    path = Path(path)
    if not path.is_file():
        raise MapFileError(path, "no such file")
    header = _png_header(path)
    arr = _read_png16(path) if header is not None and header[0] == 16 else _decode_pil(path)
    arr = _colour_channels(path, arr)
    c = arr.shape[2]
    t = torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1).contiguous()
    if channels == 3 and c == 1:
        t = t.expand(3, -1, -1).contiguous()
    elif channels == 1 and c == 3:
        if not (torch.allclose(t[0], t[1], atol=1 / 255) and torch.allclose(t[0], t[2], atol=1 / 255)):
            raise MapFileError(path, "expected a grey image, found different R, G, B channels")
        t = t.mean(dim=0, keepdim=True)
    return t


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _tag_png(data: bytes, encoding: str | None, note: str | None) -> bytes:
    """``data`` (a PNG file) with the colour chunks of ``encoding`` and a ``tEXt Comment``
    holding ``note`` inserted right after IHDR (before any PLTE or IDAT, where they must be)."""
    chunks = list(_COLOUR_CHUNKS[encoding]) if encoding else []
    if note:
        chunks.append((b"tEXt", b"Comment\x00" + note.encode("latin-1", "replace")))
    end_of_ihdr = len(_PNG_MAGIC) + 8 + 13 + 4
    extra = b"".join(_png_chunk(kind, body) for kind, body in chunks)
    return data[:end_of_ihdr] + extra + data[end_of_ihdr:]


def read_png_encoding(path) -> str | None:
    """``"srgb"`` or ``"linear"`` as a PNG's colour chunks say (cICP first, then sRGB, then a
    gAMA of 1/2.2 or 1.0), or None when it says neither (or is not a PNG)."""
    with open(path, "rb") as f:
        data = f.read()
    if not data.startswith(_PNG_MAGIC):
        return None
    found: dict[bytes, bytes] = {}
    at = len(_PNG_MAGIC)
    while at + 8 <= len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind = data[at + 4 : at + 8]
        if kind in (b"IDAT", b"IEND"):
            break
        found.setdefault(kind, data[at + 8 : at + 8 + length])
        at += 12 + length
    if len(found.get(b"cICP", b"")) == 4:
        return {13: "srgb", 8: "linear"}.get(found[b"cICP"][1])
    if b"sRGB" in found:
        return "srgb"
    if len(found.get(b"gAMA", b"")) == 4:
        gamma = struct.unpack(">I", found[b"gAMA"])[0]
        return {45455: "srgb", 100000: "linear"}.get(gamma)
    return None


def write_image(
    path, image: Tensor, *, bits: int = 8, encoding: str | None = None, note: str | None = None
) -> Path:
    """Write ``(C, H, W)`` or ``(H, W)`` values in ``[0, 1]`` (clamped) as an 8/16-bit PNG.

    ``encoding`` (``"srgb"`` or ``"linear"``) says how the values given are encoded and is
    written into the file's colour chunks (see the module); the values are stored as given.
    ``note`` goes into a ``tEXt Comment`` chunk. The parent folder is created; the file is
    written through :func:`~svbrdf_render.plumbing.atomic.atomic_output`, so a failure leaves no
    half-written image and raises an :class:`~svbrdf_render.errors.OutputError` naming ``path``.
    """
    path = Path(path)
    if bits not in (8, 16):
        raise ValueError(f"write_image: bits must be 8 or 16, got {bits}")
    if encoding is not None and encoding not in ENCODINGS:
        raise ValueError(f"write_image: encoding must be one of {ENCODINGS} or None, got {encoding!r}")
    t = image.detach().float().cpu()
    if t.dim() == 2:
        t = t.unsqueeze(0)
    if t.dim() != 3 or t.shape[0] not in (1, 3):
        raise ValueError(f"write_image: expected (1|3, H, W) or (H, W), got {tuple(image.shape)}")
    arr = t.nan_to_num(0.0).clamp(0, 1).permute(1, 2, 0).numpy()
    with atomic_output(path) as tmp:
        if bits == 16:
            png = _pypng()
            q = np.round(arr * 65535).astype(np.uint16)
            h, w, c = q.shape
            writer = png.Writer(w, h, greyscale=(c == 1), bitdepth=16)
            with open(tmp, "wb") as f:
                writer.write(f, q.reshape(h, w * c))
        else:
            Image = _pil()
            q = np.round(arr * 255).astype(np.uint8)
            Image.fromarray(q[..., 0] if q.shape[2] == 1 else q).save(tmp, format="PNG")
        if encoding or note:
            tmp.write_bytes(_tag_png(tmp.read_bytes(), encoding, note))
    return path


def write_exr(path, image: Tensor, *, half: bool = True) -> Path:
    """Write ``(C, H, W)`` or ``(H, W)`` linear values as an OpenEXR file (ZIP-compressed,
    half floats unless ``half=False``; channels ``Y`` or ``R, G, B``), atomically.

    Needs the ``exr`` extra (the ``OpenEXR`` package). Values are not clamped; NaN becomes 0.
    """
    exr = require("OpenEXR", "OpenEXR", "writing OpenEXR files", extra="exr")
    path = Path(path)
    t = image.detach().float().cpu()
    if t.dim() == 2:
        t = t.unsqueeze(0)
    if t.dim() != 3 or t.shape[0] not in (1, 3):
        raise ValueError(f"write_exr: expected (1|3, H, W) or (H, W), got {tuple(image.shape)}")
    # C order: the bindings read the buffer as laid out row by row, whatever numpy's strides say
    arr = np.ascontiguousarray(t.nan_to_num(0.0).permute(1, 2, 0).numpy(), np.float16 if half else np.float32)
    channels = {"Y": np.ascontiguousarray(arr[..., 0])} if arr.shape[2] == 1 else {"RGB": arr}
    header = {"compression": exr.ZIP_COMPRESSION, "type": exr.scanlineimage}
    with atomic_output(path) as tmp:
        exr.File(header, channels).write(str(tmp))
    return path


def write_gif(path, frames: Tensor, ms: int = 80) -> Path:
    """``frames`` (linear, ``(N, 3, H, W)``) as a looping GIF of ``ms`` milliseconds a frame,
    sRGB-encoded, atomically. One palette for every frame, built from all of them (every 4th
    pixel): a palette per frame (Pillow's default) took 1.5 s of a 256 px capture's 4.7 s, and
    flickered between frames."""
    Image = _pil()
    pixels = (linear_to_srgb(frames) * 255).round().byte().permute(0, 2, 3, 1).numpy()
    montage = Image.fromarray(np.ascontiguousarray(np.concatenate([p[::4, ::4] for p in pixels])))
    palette = montage.quantize(256, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(p).quantize(palette=palette) for p in pixels]
    with atomic_output(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=ms, loop=0)
    return Path(path)


class Des18Sample(NamedTuple):
    """A Des18 strip: the input photo ``(1, 3, S, S)`` and its maps (batch of one)."""

    input: Tensor
    svbrdf: SVBRDF


def read_des18(path) -> Des18Sample:
    """Read a Deschaintre 2018 strip (five square tiles side by side)."""
    path = Path(path)
    img = read_image(path, channels=None)
    c, h, w = img.shape
    if c != 3:
        raise MapFileError(
            path, "is a grey image", "a Des18 strip needs RGB tiles (the normal map has 3 channels)"
        )
    if w % 5 != 0 or w // 5 != h:
        tiles = w / h if h else 0
        if w % h == 0 and w // h != 5:
            raise MapFileError(
                path,
                f"has {w // h} square tiles ({w}x{h}), expected 5",
                "input | normal | diffuse | roughness | specular",
            )
        raise MapFileError(
            path,
            f"is {w}x{h}: not five square tiles (width/height = {tiles:.3f}, expected 5)",
            "a Des18 strip is 5 tiles of HxH side by side",
        )
    s = h
    tile = [img[:, :, i * s : (i + 1) * s].unsqueeze(0) for i in range(5)]
    svbrdf = SVBRDF(
        decode_normal(tile[1]),
        tile[2],
        tile[3].mean(dim=1, keepdim=True),
        tile[4],
    )
    return Des18Sample(tile[0], svbrdf)


def _single(svbrdf: SVBRDF, what: str) -> SVBRDF:
    if svbrdf.batch_size != 1:
        raise ValueError(f"{what}: expected an SVBRDF with batch size 1, got {svbrdf.batch_size}")
    return svbrdf


def _encode_maps(svbrdf: SVBRDF) -> dict[str, Tensor]:
    n = safe_normalize(svbrdf.normal.float(), dim=1)
    return {
        "normal": encode_normal(n)[0],
        "diffuse": svbrdf.diffuse[0],
        "roughness": svbrdf.roughness[0],
        "specular": svbrdf.specular[0],
    }


def write_des18(path, input_image: Tensor, svbrdf: SVBRDF, *, bits: int = 8) -> Path:
    """Write a Des18 strip from an input ``(1|3, S, S)`` or ``(1, 3, S, S)`` and its maps."""
    svbrdf = _single(svbrdf, "write_des18")
    x = input_image.detach().float().cpu()
    if x.dim() == 4:
        x = x[0]
    if x.shape != (3, *svbrdf.size):
        raise ValueError(
            f"write_des18: input image {tuple(x.shape)} does not match the maps "
            f"(3, {svbrdf.size[0]}, {svbrdf.size[1]})"
        )
    maps = _encode_maps(svbrdf.detach().to("cpu", torch.float32))
    tiles = [x, maps["normal"], maps["diffuse"], maps["roughness"].expand(3, -1, -1), maps["specular"]]
    return write_image(path, torch.cat(tiles, dim=2), bits=bits)


def _find_map(folder: Path, name: str) -> Path | None:
    for ext in _MAP_EXTENSIONS:
        for cand in (folder / f"{name}{ext}", folder / f"{name}{ext.upper()}"):
            if cand.is_file():
                return cand
    return None


def read_map_folder(folder, *, albedo_encoding: str = "auto") -> SVBRDF:
    """Read ``normal``, ``diffuse``, ``roughness``, ``specular`` images from a folder.

    ``albedo_encoding="srgb"`` decodes diffuse and specular from sRGB (most texture
    tools save albedos that way); ``"linear"`` takes them as stored, like Des18; ``"auto"``
    (default) does what each PNG's colour chunks say (:func:`read_png_encoding`) and takes
    an untagged file as stored.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise MapFileError(folder, "is not a folder of maps")
    if albedo_encoding not in ("auto", *ENCODINGS):
        raise ValueError(f"albedo_encoding must be 'auto', 'linear' or 'srgb', got {albedo_encoding!r}")
    paths = {name: _find_map(folder, name) for name in MAP_NAMES}
    missing = [n for n, p in paths.items() if p is None]
    if missing:
        present = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in _MAP_EXTENSIONS)
        raise MapFileError(
            folder,
            f"missing map(s) {', '.join(missing)}",
            f"expected normal/diffuse/roughness/specular.png; found {present or 'no images'}",
        )
    normal = read_image(paths["normal"], channels=None)
    if normal.shape[0] != 3:
        raise MapFileError(paths["normal"], "is a grey image", "a normal map needs 3 channels")
    maps = {
        "normal": normal,
        "diffuse": read_image(paths["diffuse"], channels=3),
        "roughness": read_image(paths["roughness"], channels=1),
        "specular": read_image(paths["specular"], channels=3),
    }
    size = maps["normal"].shape[1:]
    for name, t in maps.items():
        if t.shape[1:] != size:
            raise MapFileError(
                paths[name],
                f"is {t.shape[2]}x{t.shape[1]}, the normal map {size[1]}x{size[0]}",
                "all four maps must have the same size",
            )
    for name in ("diffuse", "specular"):
        encoding = albedo_encoding
        if encoding == "auto":
            encoding = read_png_encoding(paths[name]) or "linear"
        if encoding == "srgb":
            maps[name] = srgb_to_linear(maps[name])
    return SVBRDF(
        decode_normal(maps["normal"].unsqueeze(0)),
        maps["diffuse"].unsqueeze(0),
        maps["roughness"].unsqueeze(0),
        maps["specular"].unsqueeze(0),
    )


def write_map_folder(folder, svbrdf: SVBRDF, *, bits: int = 8) -> dict[str, Path]:
    """Write the four maps of a single material as PNGs; returns their paths."""
    svbrdf = _single(svbrdf, "write_map_folder")
    folder = Path(folder)
    maps = _encode_maps(svbrdf.detach().to("cpu", torch.float32))
    return {name: write_image(folder / f"{name}.png", t, bits=bits) for name, t in maps.items()}
