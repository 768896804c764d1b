"""Deschaintre 2018 ("Des18") folders as a torch Dataset.

A Des18 strip is one PNG of five square tiles, ``input | normal | diffuse | roughness |
specular`` (the map conventions of docs/svbrdf-render.md, "The renderer in one screen");
:func:`svbrdf_render.read_des18` decodes it.
Two folder layouts are accepted:

- a folder of strips, like ``DATA/des18-dev`` (``0000004;MatAXMatB;varAXvarB.png``);
- the published layout, a folder holding ``trainBlended/`` and/or ``testBlended/``; ``split``
  picks the subfolder (passing the subfolder itself works too).

Training takes a random ``crop`` from the tile and one of the eight transforms of the square
(quarter turns, flips, transposes), applied alike to the photo and to the maps; testing takes
the centre crop (:meth:`SVBRDF.center_crop`'s window) untransformed.

``fov="resize"`` keeps the field of view a model trains at (:mod:`..fov`): a test sample is the
whole tile resized to ``crop``, and a training tile is first resized by ``crop / 256`` so that
its random ``crop`` window covers the same share of the surface as Des18's own 256-of-288
training crops, at any resolution. ``fov="crop"`` (the default, and Des18's protocol at 256 px)
cuts windows from the tile as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, read_des18

__all__ = ["Des18Folder", "Des18Crop", "SPLIT_FOLDERS", "FOV_MODES", "dihedral", "dihedral_image"]

#: The subfolder of each split in the published data set.
SPLIT_FOLDERS = {"train": "trainBlended", "test": "testBlended"}

#: Number of transforms of the square: 4 quarter turns, each with or without a mirror.
DIHEDRAL_COUNT = 8
#: The crop size Des18 trains at; ``fov="resize"`` scales tiles by ``crop / DES18_CROP``.
DES18_CROP = 256
#: How a sample is brought to ``crop`` pixels (see the module doc).
FOV_MODES = ("crop", "resize")


class Des18Crop(NamedTuple):
    """Where a sample's window lies and how it is transformed.

    The transform applies to the whole tile first; the window ``[top:top+crop,
    left:left+crop]`` is then taken from the transformed tile.
    """

    top: int
    left: int
    #: 0-3: that many counter-clockwise quarter turns; 4-7: the same, then a left-right mirror.
    dihedral: int


def dihedral(svbrdf: SVBRDF, k: int) -> SVBRDF:
    """Transform ``k`` (0-7) of the square on maps; normals turn and mirror with the pixels."""
    out = svbrdf.rot90(k % 4)
    return out.flip_horizontal() if k >= 4 else out


def dihedral_image(image: Tensor, k: int) -> Tensor:
    """The same transform ``k`` on an image ``(..., C, H, W)`` (pixels only)."""
    out = torch.rot90(image, k % 4, dims=(-2, -1))
    return out.flip(-1) if k >= 4 else out


def _generator(seed: int, epoch: int, index: int) -> torch.Generator:
    """A generator for one sample of one epoch; SeedSequence mixes the three numbers well, so
    neighbouring indices or epochs do not get correlated streams."""
    words = np.random.SeedSequence([seed, epoch, index]).generate_state(2, dtype=np.uint32)
    return torch.Generator().manual_seed(int(words[0]) << 32 | int(words[1]))


def _strips(folder: Path) -> list[Path]:
    # Names starting with "." are hidden files (macOS "._x.png" resource forks, temporaries).
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() == ".png" and not p.name.startswith(".") and p.is_file()
    )


class Des18Folder(Dataset):
    """Samples of a Des18 folder, decoded when indexed (listing the files is all construction does).

    Args:
        root: a folder of strips, or a folder holding ``trainBlended/`` / ``testBlended/``.
        split: ``"train"`` or ``"test"``: the subfolder to read when ``root`` has them, and the
            defaults of ``random_crop`` and ``augment``.
        crop: side of the square window in pixels; ``None`` keeps the whole tile.
        augment: apply one of the 8 transforms of the square, drawn per sample (default: on
            for ``"train"``, off for ``"test"``).
        random_crop: draw the window's position per sample; otherwise take the centre
            (default: on for ``"train"``, off for ``"test"``).
        seed: with the epoch (:meth:`set_epoch`) and the index, fixes every random draw, so
            an epoch reproduces exactly whichever worker loads which sample.
        fov: ``"crop"`` cuts ``crop``-pixel windows from the tile as it is; ``"resize"`` brings
            the tile to the model's field of view first (see the module doc).

    Each sample is the dict of :mod:`svbrdf_train.data.sample`: ``input`` ``(3, crop, crop)``
    linear photo in ``[0, 1]``, ``maps`` ``(10, crop, crop)``, ``name`` the file name.

    Example:
        >>> data = Des18Folder("DATA/des18-dev", split="test", crop=256)
        >>> data[0]["maps"].shape
        torch.Size([10, 256, 256])
    """

    def __init__(
        self,
        root,
        split: str = "train",
        crop: int | None = 256,
        augment: bool | None = None,
        *,
        random_crop: bool | None = None,
        seed: int = 0,
        fov: str = "crop",
    ):
        if fov not in FOV_MODES:
            raise DataError(f"Des18Folder: fov must be one of {', '.join(FOV_MODES)}, got {fov!r}")
        if split not in SPLIT_FOLDERS:
            raise DataError(f"Des18Folder: split must be 'train' or 'test', got {split!r}")
        if crop is not None and (isinstance(crop, bool) or not isinstance(crop, int) or crop <= 0):
            raise DataError(f"Des18Folder: crop must be a positive number of pixels or None, got {crop!r}")
        if not isinstance(seed, int) or seed < 0:
            raise DataError(f"Des18Folder: seed must be an integer >= 0, got {seed!r}")
        self.root = Path(root)
        self.split = split
        self.crop = crop
        self.augment = split == "train" if augment is None else bool(augment)
        self.random_crop = split == "train" if random_crop is None else bool(random_crop)
        self.seed = seed
        self.fov = fov
        self.epoch = 0
        self.folder = self._find_folder()
        self.files = _strips(self.folder)
        if not self.files:
            raise DataError(
                f"{self.folder}: no Des18 strips (*.png) found; expected a folder of 5-tile PNG strips "
                "(input | normal | diffuse | roughness | specular, like des18-dev) or a folder holding "
                f"{SPLIT_FOLDERS['train']}/ and/or {SPLIT_FOLDERS['test']}/"
            )

    def _find_folder(self) -> Path:
        if not self.root.is_dir():
            what = "is a file" if self.root.exists() else "does not exist"
            raise DataError(
                f"{self.root}: {what}; give the folder that holds the Des18 strips "
                f"(or its {SPLIT_FOLDERS['train']}/ and {SPLIT_FOLDERS['test']}/ subfolders)"
            )
        sub = self.root / SPLIT_FOLDERS[self.split]
        if sub.is_dir():
            return sub
        other = self.root / SPLIT_FOLDERS["test" if self.split == "train" else "train"]
        if other.is_dir() and not _strips(self.root):
            raise DataError(
                f"{self.root}: has {other.name}/ but no {sub.name}/ for split={self.split!r}; "
                f"pass split={'test' if self.split == 'train' else 'train'!r} or the folder of the strips"
            )
        return self.root

    def __len__(self) -> int:
        return len(self.files)

    def set_epoch(self, epoch: int) -> None:
        """Draw other crops and transforms from now on (call it each epoch, like DistributedSampler's)."""
        self.epoch = int(epoch)

    def placement(self, index: int, tile: int) -> Des18Crop:
        """Window and transform of sample ``index`` this epoch, for tiles of ``tile`` pixels."""
        crop = tile if self.crop is None else self.crop
        if not (self.random_crop or self.augment):
            return Des18Crop((tile - crop) // 2, (tile - crop) // 2, 0)
        g = _generator(self.seed, self.epoch, index)
        # Always draw both, so that the window of a sample does not depend on `augment`.
        top, left = (int(v) for v in torch.randint(0, tile - crop + 1, (2,), generator=g))
        k = int(torch.randint(0, DIHEDRAL_COUNT, (1,), generator=g))
        if not self.random_crop:
            top = left = (tile - crop) // 2
        return Des18Crop(top, left, k if self.augment else 0)

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(f"Des18Folder: index {index} out of range for {len(self)} samples")
        index %= len(self)
        path = self.files[index]
        sample = read_des18(path)  # a damaged file raises MapFileError naming it
        tile = sample.svbrdf.size[0]
        crop = tile if self.crop is None else self.crop
        if self.fov == "resize" and crop != tile:
            from ..fov import resize_maps, resize_photo

            side = crop
            if self.random_crop:  # the share of the surface Des18's own 256-of-288 crops cover
                side = min(tile, max(crop, round(tile * crop / DES18_CROP)))
            sample = type(sample)(resize_photo(sample.input, side), resize_maps(sample.svbrdf, side))
            tile = side
        if crop > tile:
            raise DataError(
                f"{path}: tiles are {tile}x{tile} pixels, smaller than the crop of {crop}; "
                f"use a crop of at most {tile} pixels, or whole tiles (crop=None; --full on the command line)"
            )
        top, left, k = self.placement(index, tile)
        # Mirroring and turning the photo along with the maps gives the photo of the transformed
        # maps under the transformed flash. Des18's flashes sit 0.1-0.3 half-widths off the axis
        # (fit_flash), so the light moves with the transform: still a photo the data set could
        # hold, since its flash positions are spread around the centre.
        maps = dihedral(sample.svbrdf, k).crop(top, left, crop)
        photo = dihedral_image(sample.input, k)[..., top : top + crop, left : left + crop]
        return {
            "input": photo[0].contiguous(),
            "maps": maps.pack()[0].contiguous(),
            "name": path.name,
        }

    def __repr__(self) -> str:
        return (
            f"Des18Folder({str(self.folder)!r}, split={self.split!r}, {len(self)} strips, crop={self.crop}, "
            f"random_crop={self.random_crop}, augment={self.augment}, seed={self.seed}, fov={self.fov!r})"
        )
