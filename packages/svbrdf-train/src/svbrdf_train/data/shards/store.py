"""HDF5 shards: samples written once, read many times by several DataLoader workers.

Layout of a shard (``N`` samples at ``R x R``, ``bits`` 8 or 16)::

    /input      (N, R, R, 3) uint8|uint16   the photo, linear, clamped to [0, 1]
    /normal     (N, R, R, 3) uint8|uint16   (n + 1) / 2 of the unit normal
    /diffuse    (N, R, R, 3) uint8|uint16   linear albedo
    /roughness  (N, R, R, 1) uint8|uint16
    /specular   (N, R, R, 3) uint8|uint16   linear albedo (F0)
    /name       (N,)         utf-8 string   where the sample came from (file name, procedural:seed:index)

Every value ``v`` in ``[0, 1]`` is stored as ``round(v * (2**bits - 1))``. The photo is stored
at the same depth as the maps: it is linear and clipped at 1 like a sensor's (the Des18
photos themselves are 8-bit linear), so the stored error is at most half a step, 0.002 at
8 bits. Reading divides back and re-normalises the normals.

Each sample is one chunk per dataset (a read touches only its own sample), compressed with
:data:`~.format.COMPRESSION` and checksummed (Fletcher-32), so a damaged chunk is an error,
never a silently wrong sample. The root attributes say what the file holds (``format``,
``format_version``, ``resolution``, ``bits``, ``count``, ``created_by``), where it came from
(``source`` and what the writer was given: generator version, seed, families, source folder)
and whether writing finished (``complete``, set last). A shard is written under a temporary
name next to its target and renamed when complete, so a killed or failed write never leaves a
file under the target's name.

The format's constants, its attributes and the check of a shard
(:func:`~.format.inspect_shard`) are in :mod:`.format`; this module writes and reads shards.
"""

from __future__ import annotations

import bisect
import contextlib
import gc
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from svbrdf_models.errors import DataError
from svbrdf_render import encode_normal, safe_normalize
from svbrdf_render.plumbing import is_write_failure, temporary_path, write_failure

from ...errors import ShardError
from .format import (
    COMPRESSION,
    FORMAT,
    FORMAT_VERSION,
    HOW_TO_REMAKE,
    SHARD_DATASETS,
    WRITER_ATTRS,
    created_by,
    inspect_shard,
    open_shard,
    to_attr,
)

__all__ = ["ShardWriter", "ShardDataset", "write_shard"]


# -- writing ------------------------------------------------------------------------------


def _quantise(x: Tensor, bits: int) -> np.ndarray:
    """``(B, C, H, W)`` values in [0, 1] (clamped) -> ``(B, H, W, C)`` unsigned integers."""
    top = (1 << bits) - 1
    q = (x.detach().float().cpu().clamp(0, 1) * top).round()
    return q.permute(0, 2, 3, 1).numpy().astype(np.uint8 if bits == 8 else np.uint16)


class ShardWriter:
    """Write samples to a new shard; the file appears under ``path`` only when complete.

    Args:
        path: the shard to create (``.h5``).
        resolution: side of every sample in pixels.
        bits: 8 or 16 bits per stored value.
        attrs: provenance recorded as root attributes (``source``, ``generator_version``,
            ``seed``, ``families``, ...): strings, numbers, bools and lists of them as HDF5
            attributes, anything else as JSON text.
        overwrite: replace an existing ``path`` (only once the new shard is complete).
        compression: h5py filter arguments of the image datasets (default
            :data:`~.format.COMPRESSION`).

    Use it as a context manager: leaving the block normally completes the shard; an exception
    (KeyboardInterrupt included) deletes the temporary file and leaves ``path`` as it was.

    Example:
        >>> from svbrdf_train.data import ProceduralMaterials
        >>> materials = ProceduralMaterials(count=16, resolution=32, seed=0)
        >>> with ShardWriter("train.h5", 32, attrs={"source": "procedural", "seed": 0}) as shard:
        ...     shard.extend(materials.batch(range(16)))  # input (B, 3, R, R), maps (B, 10, R, R), name
    """

    def __init__(
        self,
        path,
        resolution: int,
        *,
        bits: int = 8,
        attrs: Mapping[str, Any] | None = None,
        overwrite: bool = False,
        compression: Mapping[str, Any] | None = None,
    ):
        if bits not in (8, 16):
            raise DataError(f"ShardWriter: bits must be 8 or 16, got {bits!r}")
        if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution <= 0:
            raise DataError(
                f"ShardWriter: resolution must be a positive number of pixels, got {resolution!r}"
            )
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise DataError(f"{self.path}: already exists; choose another name or allow overwriting it")
        self.resolution = resolution
        self.bits = bits
        self.count = 0
        self.compression = dict(COMPRESSION if compression is None else compression)
        self._tmp = temporary_path(self.path)
        self._file: h5py.File | None = None
        self._datasets: dict[str, h5py.Dataset] = {}
        with self._writing():
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # No chunk cache: a chunk is one whole sample, written (and a failure seen) at once.
            self._file = h5py.File(self._tmp, "w", rdcc_nbytes=0)
            self._create(dict(attrs or {}))
            self._file.flush()

    def _create(self, attrs: dict[str, Any]) -> None:
        f = self._file
        r = self.resolution
        dtype = np.uint8 if self.bits == 8 else np.uint16
        for name, channels in SHARD_DATASETS.items():
            f.create_dataset(
                name,
                shape=(0, r, r, channels),
                maxshape=(None, r, r, channels),
                chunks=(1, r, r, channels),
                dtype=dtype,
                fletcher32=True,
                track_times=False,  # the same samples give the same bytes
                **self.compression,
            )
        f.create_dataset(
            "name", shape=(0,), maxshape=(None,), chunks=(1024,), dtype=h5py.string_dtype(), track_times=False
        )
        # Handles kept open: h5py flushes a dataset when its handle is freed, and a write that
        # fails there is only printed, then crashes the process (seen on a full disk).
        self._datasets = {name: f[name] for name in (*SHARD_DATASETS, "name")}
        clash = WRITER_ATTRS & set(attrs)
        if clash:
            raise DataError(f"ShardWriter: attrs may not set {sorted(clash)}; the writer records them")
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["resolution"] = r
        f.attrs["bits"] = self.bits
        f.attrs["encoding"] = (
            f"value = stored / {(1 << self.bits) - 1}; normal = 2 value - 1; input and albedos linear"
        )
        f.attrs["created_by"] = created_by()
        for key, value in attrs.items():
            if value is not None:
                f.attrs[key] = to_attr(value)
        f.attrs["count"] = 0
        f.attrs["complete"] = False

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def append(self, sample: Mapping[str, Any]) -> None:
        """Add one sample: ``input`` ``(3, R, R)``, ``maps`` ``(10, R, R)``, ``name`` str."""
        keys = ("input", "maps", "name")
        self.extend({k: [v] if k == "name" else v[None] for k, v in sample.items() if k in keys})

    def extend(self, batch: Mapping[str, Any]) -> None:
        """Add a batch: ``input`` ``(B, 3, R, R)``, ``maps`` ``(B, 10, R, R)``, ``name`` B strings."""
        if self._file is None:
            raise DataError(f"{self.path}: the shard is closed; open a new ShardWriter")
        missing = [k for k in ("input", "maps", "name") if k not in batch]
        if missing:
            raise DataError(
                f"{self.path}: a sample to write has no {', '.join(missing)} (found {sorted(batch)}); "
                "a shard stores a photo, its maps and a name"
            )
        x, maps, names = batch["input"], batch["maps"], batch["name"]
        names = [names] if isinstance(names, str) else list(names)
        r = self.resolution
        b = len(names)
        for key, t, c in (("input", x, 3), ("maps", maps, 10)):
            if not isinstance(t, Tensor) or tuple(t.shape) != (b, c, r, r):
                shape = tuple(t.shape) if isinstance(t, Tensor) else type(t).__name__
                raise DataError(
                    f"{self.path}: sample {names[0] if names else '?'}: '{key}' is {shape}, "
                    f"expected {(b, c, r, r)} (the shard's resolution is {r})"
                )
            bad = ~torch.isfinite(t.detach()).flatten(1).all(dim=1)
            if bool(bad.any()):
                first = names[int(bad.nonzero()[0])]
                raise DataError(f"{self.path}: sample {first}: '{key}' holds NaN or infinite values")
        normal = safe_normalize(maps[:, 0:3].detach().float(), dim=1)
        arrays = {
            "input": _quantise(x, self.bits),
            "normal": _quantise(encode_normal(normal), self.bits),
            "diffuse": _quantise(maps[:, 3:6], self.bits),
            "roughness": _quantise(maps[:, 6:7], self.bits),
            "specular": _quantise(maps[:, 7:10], self.bits),
        }
        arrays["name"] = np.array([str(s) for s in names], dtype=h5py.string_dtype())
        n = self.count
        with self._writing():
            for name, array in arrays.items():
                ds = self._datasets[name]
                ds.resize(n + b, axis=0)
                ds[n : n + b] = array
            self._file.flush()
        self.count = n + b

    def close(self) -> Path:
        """Mark the shard complete and move it to ``path``; returns ``path``."""
        if self._file is None:
            return self.path
        with self._writing():
            self._file.attrs["count"] = self.count
            self._file.attrs["complete"] = True
            self._datasets = {}
            self._file.flush()
            self._file.close()
            self._file = None
            with open(self._tmp, "rb+") as f:
                os.fsync(f.fileno())
            os.replace(self._tmp, self.path)
        return self.path

    @contextlib.contextmanager
    def _writing(self):
        """Any failure: :meth:`abort`; a write the system refused: one line naming :attr:`path`."""
        try:
            yield
        except BaseException as e:
            self.abort()
            if isinstance(e, DataError) or not is_write_failure(e):
                raise
            raise write_failure(self.path, e) from None

    def abort(self) -> None:
        """Give up: close and delete the temporary file; ``path`` is left as it was.

        After a failed write (a full disk) HDF5 still holds data it will try to write when the
        file closes. The temporary file is emptied first, which frees its space, so that the
        close can finish; what HDF5 prints about the failures it meets is dropped (the caller
        raises one error naming the shard).
        """
        self._datasets = {}
        hook = sys.unraisablehook
        sys.unraisablehook = lambda _: None
        try:
            with contextlib.suppress(OSError):
                os.truncate(self._tmp, 0)
            if self._file is not None:
                with contextlib.suppress(Exception):
                    self._file.close()
            self._file = None
            gc.collect()  # free h5py objects now, while their complaints are dropped
        finally:
            sys.unraisablehook = hook
        with contextlib.suppress(OSError):
            self._tmp.unlink(missing_ok=True)


def write_shard(
    path,
    batches: Iterable[Mapping[str, Any]],
    resolution: int,
    *,
    bits: int = 8,
    attrs: Mapping[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write batched samples (dicts as :meth:`ShardWriter.extend` takes) to a new shard."""
    with ShardWriter(path, resolution, bits=bits, attrs=attrs, overwrite=overwrite) as shard:
        for batch in batches:
            shard.extend(batch)
    return shard.path


# -- reading ------------------------------------------------------------------------------


def _decode(arrays: dict[str, np.ndarray], bits: int) -> tuple[Tensor, Tensor]:
    """Stored ``(H, W, C)`` integers -> the photo ``(3, H, W)`` and the packed maps ``(10, H, W)``."""
    stored = np.concatenate([arrays[name] for name in SHARD_DATASETS], axis=-1)  # (H, W, 13)
    values = torch.from_numpy(stored).permute(2, 0, 1).float().mul_(1.0 / ((1 << bits) - 1))
    normal = values[3:6].mul_(2).sub_(1)  # svbrdf_render.decode_normal, in place (a hot path)
    # No zero-length normal can come out: 2 q / top - 1 is never 0 for an odd top = 2**bits - 1,
    # so every component is at least 1 / top away from 0, and a plain division is safe.
    normal.div_(normal.square().sum(dim=0, keepdim=True).sqrt_())
    return values[:3], values[3:]


class ShardDataset(Dataset):
    """The samples of one or several shards, in order, as one dataset.

    Args:
        paths: a shard or a sequence of shards. All are checked when the dataset is made
            (:func:`~.format.inspect_shard`); they must share one resolution (8- and 16-bit
            shards mix freely: each decodes with its own depth).

    Each sample is the dict of :mod:`svbrdf_train.data.sample`: ``input`` ``(3, R, R)``,
    ``maps`` ``(10, R, R)`` float32, ``name`` str. A sample whose data cannot be read (a
    damaged chunk) raises :class:`ShardError` naming the file and the sample; none is
    skipped.

    Files are opened on first read in each process and never pickled, so the dataset is safe
    with DataLoader workers (fork or spawn) and with DistributedSampler.

    Example:
        >>> from torch.utils.data import DataLoader
        >>> from svbrdf_train.data import ProceduralMaterials
        >>> for seed in (0, 1):
        ...     with ShardWriter(f"train-{seed}.h5", 32) as shard:
        ...         shard.extend(ProceduralMaterials(count=4, resolution=32, seed=seed).batch(range(4)))
        >>> data = ShardDataset(["train-0.h5", "train-1.h5"])
        >>> len(data), data[5]["maps"].shape
        (8, torch.Size([10, 32, 32]))
        >>> loader = DataLoader(data, batch_size=8, shuffle=True, num_workers=2)
    """

    def __init__(self, paths):
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        self.paths = [Path(p) for p in paths]
        if not self.paths:
            raise ShardError("ShardDataset: no shard given; pass the path of at least one .h5 shard")
        self.infos = [inspect_shard(p) for p in self.paths]
        first = self.infos[0]
        for info in self.infos[1:]:
            if info.resolution != first.resolution:
                raise ShardError(
                    f"{info.path}: samples are {info.resolution}x{info.resolution}, but {first.path} holds "
                    f"{first.resolution}x{first.resolution}; shards read together must share one "
                    "resolution (make or import them again at one resolution)"
                )
        self.resolution = first.resolution
        self._ends = np.cumsum([info.count for info in self.infos]).tolist()
        self._files: dict[int, h5py.File] = {}
        self._pid = os.getpid()

    def __len__(self) -> int:
        return self._ends[-1]

    def locate(self, index: int) -> tuple[int, int]:
        """``(shard number, sample number in that shard)`` of a dataset index."""
        if not -len(self) <= index < len(self):
            raise IndexError(f"ShardDataset: index {index} out of range for {len(self)} samples")
        index %= len(self)
        shard = bisect.bisect_right(self._ends, index)
        return shard, index - (self._ends[shard - 1] if shard else 0)

    def _file(self, shard: int) -> h5py.File:
        if os.getpid() != self._pid:
            # A forked worker inherited the parent's handles; HDF5 handles must not be shared
            # across processes, so this process opens its own.
            self._files = {}
            self._pid = os.getpid()
        f = self._files.get(shard)
        if f is None:
            f = self._files[shard] = open_shard(self.paths[shard])
        return f

    def __getitem__(self, index: int) -> dict:
        shard, i = self.locate(index)
        bits = self.infos[shard].bits
        f = self._file(shard)
        try:
            arrays = {name: f[name][i] for name in SHARD_DATASETS}
            name = f["name"].asstr()[i]
        except (OSError, RuntimeError) as e:
            raise ShardError(
                f"{self.paths[shard]}: sample {i} cannot be read, the file is damaged ({e}); "
                f"{HOW_TO_REMAKE}, or leave this shard out"
            ) from None
        photo, maps = _decode(arrays, bits)
        return {"input": photo, "maps": maps, "name": name}

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_files"] = {}  # open HDF5 handles do not pickle; each process opens its own
        return state

    def close(self) -> None:
        """Close the files this process opened (they reopen on the next read)."""
        for f in self._files.values():
            f.close()
        self._files = {}

    def __repr__(self) -> str:
        names = ", ".join(str(p) for p in self.paths[:3]) + (", ..." if len(self.paths) > 3 else "")
        return f"ShardDataset([{names}], {len(self)} samples at {self.resolution}x{self.resolution})"
