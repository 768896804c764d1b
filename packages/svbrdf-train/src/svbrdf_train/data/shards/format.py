"""The shard file format: its name and version, its datasets, its attributes, and the check
that a file holds a complete shard of this format (:func:`inspect_shard`).

The layout and the encoding of the values are described in :mod:`.store`, which writes and
reads shards.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ...errors import ShardError

__all__ = ["COMPRESSION", "FORMAT", "FORMAT_VERSION", "SHARD_DATASETS", "ShardInfo", "inspect_shard"]

#: The ``format`` attribute of every shard.
FORMAT = "svbrdf-shard"
#: Bump when the layout changes; readers refuse versions newer than theirs.
FORMAT_VERSION = 1
#: Channels of each image dataset, in the order of ``SVBRDF.pack`` after the photo.
SHARD_DATASETS = {"input": 3, "normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
#: h5py filter settings of the image datasets. gzip level 4 after byte shuffling: the best
#: trade of size and read speed measured on procedural and Des18 samples (docs/measured-speed.md).
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}

#: Root attributes the writer sets itself.
WRITER_ATTRS = frozenset(
    {"format", "format_version", "resolution", "bits", "encoding", "count", "complete", "created_by"}
)
#: The advice every error about a bad shard ends with.
HOW_TO_REMAKE = "re-create it with `svbrdf-train data make` or `svbrdf-train data import`"


def created_by() -> str:
    """The ``created_by`` attribute: the versions of the packages that write a shard."""
    names = ("svbrdf-train", "svbrdf-render", "torch", "numpy", "h5py")
    versions = []
    for name in names:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:  # pragma: no cover - a source checkout
            versions.append(f"{name} unknown")
    return ", ".join(versions) + f" (HDF5 {h5py.version.hdf5_version})"


# -- attributes ---------------------------------------------------------------------------


def to_attr(value: Any) -> Any:
    """A Python value as an HDF5 attribute: scalars and lists natively, anything else as JSON."""
    if isinstance(value, (str, bool, int, float, np.generic)):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, str) for v in value):
            return np.array(list(value), dtype=h5py.string_dtype())
        if value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return np.asarray(value)
    return json.dumps(value, sort_keys=True)


def from_attr(value: Any) -> Any:
    """An HDF5 attribute as plain Python (str, int, float, bool, list)."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        return [from_attr(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


# -- checking -----------------------------------------------------------------------------


@dataclass(frozen=True)
class ShardInfo:
    """What a valid shard holds, from its attributes and dataset shapes."""

    path: Path
    count: int
    resolution: int
    bits: int
    #: Every root attribute, as plain Python values.
    attrs: dict[str, Any] = field(default_factory=dict)
    #: ``name -> (shape, dtype, compression)`` of each dataset.
    datasets: dict[str, tuple[tuple[int, ...], str, str]] = field(default_factory=dict)


def open_shard(path: Path) -> h5py.File:
    """``path`` opened for reading; a missing file, a folder or a file HDF5 cannot open: ShardError."""
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "does not exist"
        raise ShardError(f"{path}: {what}; give the path of an .h5 shard")
    try:
        return h5py.File(path, "r")
    except OSError as e:
        raise ShardError(
            f"{path}: cannot be opened as HDF5, it is truncated or corrupted ({e}); {HOW_TO_REMAKE}"
        ) from None


def inspect_shard(path) -> ShardInfo:
    """Check a shard's attributes and datasets without decoding samples; raise ShardError if bad.

    Checks: an HDF5 file of this format and a version this reader knows, marked complete,
    with every dataset present, of ``count`` samples at ``resolution`` and the dtype of
    ``bits``. Damaged sample data shows only when read (:class:`~.shards.ShardDataset` names the
    sample; ``svbrdf-train data info --check`` reads them all).
    """
    path = Path(path)
    with open_shard(path) as f:
        try:
            attrs = {key: from_attr(value) for key, value in f.attrs.items()}
        except (OSError, RuntimeError) as e:
            raise ShardError(f"{path}: its attributes cannot be read ({e}); {HOW_TO_REMAKE}") from None
        if attrs.get("format") != FORMAT:
            raise ShardError(
                f"{path}: not an svbrdf shard (attribute 'format' is {attrs.get('format')!r}, "
                f"expected {FORMAT!r}); {HOW_TO_REMAKE}"
            )
        version = attrs.get("format_version")
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise ShardError(
                f"{path}: shard format version {version!r}, this svbrdf-train reads up to "
                f"{FORMAT_VERSION}; upgrade svbrdf-train"
            )
        if attrs.get("complete") is not True:
            raise ShardError(
                f"{path}: incomplete, its writing did not finish (the 'complete' attribute is not set); "
                f"{HOW_TO_REMAKE}"
            )
        missing = [name for name in (*SHARD_DATASETS, "name") if name not in f]
        if missing:
            raise ShardError(
                f"{path}: missing dataset(s) {', '.join(missing)} (found {', '.join(sorted(f)) or 'none'}); "
                f"a shard holds input, normal, diffuse, roughness, specular and name; {HOW_TO_REMAKE}"
            )
        count, r, bits = attrs.get("count"), attrs.get("resolution"), attrs.get("bits")
        if not isinstance(count, int) or not isinstance(r, int) or bits not in (8, 16):
            raise ShardError(
                f"{path}: bad attributes count={count!r}, resolution={r!r}, bits={bits!r}; {HOW_TO_REMAKE}"
            )
        dtype = np.dtype(np.uint8 if bits == 8 else np.uint16)
        datasets = {}
        for name in (*SHARD_DATASETS, "name"):
            ds = f[name]
            if not isinstance(ds, h5py.Dataset):
                raise ShardError(f"{path}: '{name}' is a group, expected a dataset; {HOW_TO_REMAKE}")
            want = (count, r, r, SHARD_DATASETS[name]) if name in SHARD_DATASETS else (count,)
            if ds.shape != want:
                raise ShardError(
                    f"{path}: dataset '{name}' has shape {ds.shape}, expected {want} "
                    f"(count {count}, resolution {r}); {HOW_TO_REMAKE}"
                )
            if name in SHARD_DATASETS and ds.dtype != dtype:
                raise ShardError(
                    f"{path}: dataset '{name}' is {ds.dtype}, expected {dtype} for bits={bits}; "
                    + HOW_TO_REMAKE
                )
            datasets[name] = (ds.shape, str(ds.dtype), str(ds.compression or "none"))
    return ShardInfo(path, count, r, bits, attrs, datasets)
