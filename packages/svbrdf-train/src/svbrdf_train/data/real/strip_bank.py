"""Material strips decoded: read from PNGs, checked, held in memory, and kept in strip shards.

A material strip is one PNG of four square tiles, ``normal | diffuse | roughness | specular``
(:mod:`.strips` says what the values mean and how training uses them). :class:`MaterialBank`
holds the strips of a folder as 8-bit maps ``(10, S, S)``: stored normal, diffuse, roughness
(one channel), specular.

A strip shard holds the strips decoded (decoding 70 PNGs made from JPEG sources takes
seconds; reading a shard, a fraction of one)::

    /maps   (N, 10, S, S) uint8   stored normal (n + 1) / 2, diffuse, roughness, specular
    /name   (N,)          utf-8   the material's name (its strip's file stem)

one chunk per material, gzip-compressed and checksummed (Fletcher-32). Root attributes:
``format`` (:data:`STRIP_FORMAT`), ``format_version``, ``tile``, ``count``, ``source`` (the
folder it was made from), ``created_by`` and ``complete`` (set last). The file is written
under a temporary name and renamed when complete, so a failed write leaves nothing behind.

``tile`` smaller than the strips' own resizes each material with the area filter (normals
averaged as vectors and renormalised): 256 px is all a 128 px fit needs (its smallest window
is half the tile), a quarter of the memory of 512 px.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_models.errors import DataError
from svbrdf_render import decode_normal, encode_normal
from svbrdf_render.formats.mapfiles import read_image
from svbrdf_render.plumbing import temporary_path

from ...errors import ShardError
from ..shards.format import created_by

__all__ = [
    "STRIP_FORMAT",
    "STRIP_FORMAT_VERSION",
    "STRIP_TILES",
    "MaterialBank",
    "is_strip_folder",
    "read_strip",
    "read_strip_shard",
    "resize_bank",
    "strip_tensor",
    "write_strip_shard",
]

#: Tiles of a strip: normal | diffuse | roughness | specular.
STRIP_TILES = 4
#: A normal tile is refused when more than this share of its pixels decode to a length
#: further than ``NORMAL_TOLERANCE`` from 1 (8-bit storage alone moves it by < 0.01).
NORMAL_BAD_SHARE, NORMAL_TOLERANCE = 0.5, 0.2


def check_normal_tile(stored: np.ndarray, where: str) -> None:
    """Refuse a normal tile ``(3, S, S)`` of 8-bit values that is no unit vector field."""
    n = stored.astype(np.float32) * (2 / 255) - 1
    length = np.sqrt((n * n).sum(axis=0))
    bad = float(np.mean(np.abs(length - 1) > NORMAL_TOLERANCE))
    if bad > NORMAL_BAD_SHARE:
        raise DataError(
            f"{where}: its normal tile (the first) is no unit vector field: {bad:.0%} of its pixels "
            f"decode to a length far from 1 (median {float(np.median(length)):.2f}); a strip is "
            "normal | diffuse | roughness | specular with normals stored as (n + 1) / 2"
        )


def read_strip(path) -> np.ndarray:
    """A material strip as 8-bit maps ``(10, S, S)``: stored normal, diffuse, roughness,
    specular (16-bit PNGs are rounded to 8 bits).

    Raises:
        DataError: not four square tiles, or a normal tile that is no unit vector field;
            a file that cannot be read (``MapFileError``); each names the file.
    """
    path = Path(path)
    img = read_image(path, channels=3)
    _, h, w = img.shape
    if h == 0 or w != STRIP_TILES * h:
        raise DataError(
            f"{path}: is {w}x{h}, not four square tiles side by side (width = 4 x height); a material "
            "strip is normal | diffuse | roughness | specular"
        )
    q = (img * 255).round().to(torch.uint8).numpy()
    tiles = [q[:, :, i * h : (i + 1) * h] for i in range(STRIP_TILES)]
    check_normal_tile(tiles[0], str(path))
    return np.ascontiguousarray(np.concatenate([tiles[0], tiles[1], tiles[2][:1], tiles[3]]))


def _pngs(folder: Path) -> list[Path]:
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() == ".png" and not p.name.startswith(".") and p.is_file()
    )


def is_strip_folder(folder) -> bool:
    """Whether ``folder``'s first PNG is four square tiles wide (a strip folder, not Des18's five)."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    files = _pngs(folder)
    if not files:
        return False
    from PIL import Image

    with Image.open(files[0]) as im:
        w, h = im.size
    return h > 0 and w == STRIP_TILES * h


@dataclass(frozen=True)
class MaterialBank:
    """Decoded material strips: ``names[i]`` and its 8-bit maps ``maps[i]`` ``(10, S, S)``."""

    names: tuple[str, ...]
    maps: tuple[np.ndarray, ...]
    where: str

    @classmethod
    def open(cls, path) -> MaterialBank:
        """The strips of a folder of PNGs or of a strip shard (``.h5``)."""
        path = Path(path).expanduser()
        if path.suffix == ".h5" and path.is_file():
            return read_strip_shard(path)
        if not path.is_dir():
            what = "is a file that is no strip shard (.h5)" if path.exists() else "does not exist"
            raise DataError(f"{path}: {what}; give a folder of material strips or a strip shard")
        files = _pngs(path)
        if not files:
            raise DataError(
                f"{path}: no material strips (*.png) there; a strip is one PNG of four square tiles, "
                "normal | diffuse | roughness | specular"
            )
        return cls(tuple(p.stem for p in files), tuple(read_strip(p) for p in files), str(path))

    def __len__(self) -> int:
        return len(self.names)

    @property
    def tile(self) -> int:
        """The smallest tile side of the bank, in pixels."""
        return min(m.shape[-1] for m in self.maps)

    def select(self, names: Sequence[str]) -> MaterialBank:
        """The bank of ``names`` only, in this bank's order."""
        keep = set(names)
        pairs = [(n, m) for n, m in zip(self.names, self.maps, strict=True) if n in keep]
        return MaterialBank(tuple(n for n, _ in pairs), tuple(m for _, m in pairs), self.where)


def strip_tensor(maps: np.ndarray) -> Tensor:
    """8-bit bank maps ``(10, S, S)`` -> the packed float maps ``(10, S, S)`` (normals decoded)."""
    v = torch.from_numpy(np.ascontiguousarray(maps)).float().div_(255)
    return torch.cat([decode_normal(v[0:3], dim=0), v[3:]])


# -- strip shards ----------------------------------------------------------------------


#: The ``format`` attribute of a strip shard, and its layout version.
STRIP_FORMAT = "svbrdf-strips"
STRIP_FORMAT_VERSION = 1


def _resized(maps: np.ndarray, tile: int) -> np.ndarray:
    if maps.shape[-1] == tile:
        return maps
    v = strip_tensor(maps)[None]
    v = F.interpolate(v, size=(tile, tile), mode="area")[0]
    normal = F.normalize(v[0:3], dim=0)
    out = torch.cat([encode_normal(normal), v[3:]]).clamp(0, 1)
    return (out * 255).round().to(torch.uint8).numpy()


def resize_bank(bank: MaterialBank, tile: int | None) -> MaterialBank:
    """``bank`` with every material at ``tile`` pixels (None: as it is)."""
    if tile is None:
        return bank
    small = [n for n, m in zip(bank.names, bank.maps, strict=True) if m.shape[-1] < tile]
    if small:
        raise DataError(f"{bank.where}: {small[0]} is smaller than the tile of {tile} px asked for")
    return MaterialBank(bank.names, tuple(_resized(m, tile) for m in bank.maps), bank.where)


def write_strip_shard(bank: MaterialBank, path, *, overwrite: bool = False, progress=None) -> Path:
    """Write ``bank`` (one tile size) to a new strip shard at ``path``; returns ``path``."""
    import h5py

    path = Path(path)
    if path.exists() and not overwrite:
        raise DataError(f"{path}: already exists; choose another name or allow overwriting it (--force)")
    sizes = {m.shape[-1] for m in bank.maps}
    if len(sizes) != 1:
        raise DataError(f"{bank.where}: tiles of {sorted(sizes)} px; give one --tile for all")
    tile = sizes.pop()
    tmp = temporary_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs.update(format=STRIP_FORMAT, format_version=STRIP_FORMAT_VERSION, tile=tile)
            f.attrs.update(source=bank.where, created_by=created_by(), count=len(bank), complete=False)
            ds = f.create_dataset(
                "maps", shape=(len(bank), 10, tile, tile), chunks=(1, 10, tile, tile), dtype=np.uint8,
                compression="gzip", compression_opts=4, shuffle=True, fletcher32=True, track_times=False,
            )  # fmt: skip
            f.create_dataset("name", data=np.array(bank.names, dtype=h5py.string_dtype()), track_times=False)
            for i, maps in enumerate(bank.maps):
                ds[i] = maps
                if progress is not None:
                    progress(1)
            f.attrs["complete"] = True
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def read_strip_shard(path) -> MaterialBank:
    """The materials of a strip shard, decoded into memory.

    Raises:
        ShardError: not a strip shard, incomplete, of a newer version, or damaged.
    """
    import h5py

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
            if fmt != STRIP_FORMAT:
                raise ShardError(
                    f"{path}: not a strip shard (format {fmt!r}); make one with `svbrdf-train data strips`"
                )
            if not f.attrs.get("complete", False):
                raise ShardError(f"{path}: an incomplete strip shard (its writing stopped); make it again")
            if int(f.attrs.get("format_version", 0)) > STRIP_FORMAT_VERSION:
                raise ShardError(f"{path}: a strip shard of a newer version; update svbrdf-train")
            maps = f["maps"][...]
            names = tuple(f["name"].asstr()[...])
    except ShardError:
        raise
    except (OSError, KeyError, RuntimeError) as e:
        raise ShardError(f"{path}: cannot be read as a strip shard ({e}); make it again") from None
    return MaterialBank(names, tuple(np.ascontiguousarray(m) for m in maps), str(path))
