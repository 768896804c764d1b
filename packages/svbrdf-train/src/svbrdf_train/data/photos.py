"""Folders of flash photos without ground truth, for prediction and real-data evaluation.

A photo file holds either sRGB-encoded values (what phones and cameras save) or linear
radiance (the Des18 inputs, and photos prepared for them). The two cannot be told apart from
the pixels, so the reader is told which (docs/capture.md); a folder mixing both
is read as two datasets, or one with a ``pattern`` each.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path

from torch.utils.data import Dataset

from svbrdf_models.capture.photos import file_orientation, orient, square_photo
from svbrdf_models.errors import DataError
from svbrdf_render import read_image
from svbrdf_render.formats.mapfiles import srgb_to_linear

__all__ = ["PhotoFolder", "ENCODINGS", "PHOTO_EXTENSIONS"]

#: How the values of a photo file are encoded.
ENCODINGS = ("srgb", "linear")
#: File types read (case-insensitive).
PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg")


class PhotoFolder(Dataset):
    """The photos of a folder, decoded to linear values when indexed.

    Args:
        root: the folder (not searched recursively).
        encoding: ``"srgb"`` (decoded with the sRGB curve) or ``"linear"`` (taken as stored).
            Required: the pixels do not tell.
        size: side in pixels of every returned photo. Each photo is centre-cropped to a
            square of its shorter side, then resampled to ``size`` (bilinear, antialiased, on
            linear values). ``None`` keeps the square crop at the file's resolution; photos of
            different sizes then cannot share a batch.
        pattern: a shell pattern on file names (``"luo2024_*"``); files must also end in
            ``.png``, ``.jpg`` or ``.jpeg``.

    Each sample is ``{"input": (3, S, S) float32 linear in [0, 1], "name": file name}``, with
    no ``maps``; the photo is taken as displayed, its EXIF orientation applied (as ``svbrdf-train
    predict`` does) before the square crop. An unreadable file raises
    :class:`~svbrdf_render.MapFileError` naming it.

    Example:
        >>> phones = PhotoFolder("DATA/real-dev", encoding="srgb", pattern="luo2024_*", size=256)
        >>> phones[0]["input"].shape
        torch.Size([3, 256, 256])
    """

    def __init__(self, root, *, encoding: str, size: int | None = None, pattern: str = "*"):
        if encoding not in ENCODINGS:
            raise DataError(
                f"PhotoFolder: encoding must be 'srgb' (photos as cameras save them) or 'linear' "
                f"(radiance stored as is, like the Des18 inputs), got {encoding!r}"
            )
        if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size <= 0):
            raise DataError(f"PhotoFolder: size must be a positive number of pixels or None, got {size!r}")
        self.root = Path(root)
        if not self.root.is_dir():
            what = "is a file" if self.root.exists() else "does not exist"
            raise DataError(f"{self.root}: {what}; give a folder of photos (.png, .jpg)")
        self.encoding = encoding
        self.size = size
        self.pattern = pattern
        self.files = sorted(
            p
            for p in self.root.iterdir()
            if p.suffix.lower() in PHOTO_EXTENSIONS
            and not p.name.startswith(".")
            and fnmatch.fnmatchcase(p.name, pattern)
            and p.is_file()
        )
        if not self.files:
            raise DataError(
                f"{self.root}: no photos matching {pattern!r} with extension "
                f"{', '.join(PHOTO_EXTENSIONS)}; check the folder and the pattern"
            )

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(f"PhotoFolder: index {index} out of range for {len(self)} photos")
        path = self.files[index]
        photo = orient(read_image(path, channels=3), file_orientation(path))
        if self.encoding == "srgb":
            photo = srgb_to_linear(photo)
        return {"input": square_photo(photo, self.size), "name": path.name}

    def __repr__(self) -> str:
        return (
            f"PhotoFolder({str(self.root)!r}, encoding={self.encoding!r}, pattern={self.pattern!r}, "
            f"size={self.size}, {len(self)} photos)"
        )
