"""The training and validation sets of a recipe's ``data`` section.

=============  ==================================================  =====================================
source         training set                                        validation set (fixed, held out)
=============  ==================================================  =====================================
procedural     ``count`` materials of ``seed``, photographed       ``validation`` materials of
               under ``data.capture``                              ``seed + 1`` (never the same ones)
shards         every sample of the files but the last              the last ``validation`` samples
               ``validation``
des18          the folder's ``trainBlended/`` (or the strips),     ``testBlended/`` when there is one,
               random crops and the 8 symmetries                   else the last ``validation`` strips;
                                                                   whole tiles resized
materials      ``count`` samples an epoch of the strips of the     the held-out fold (``data.fold``),
               folder or strip shard (:mod:`.real.strips`):         whole tiles resized, fixed photos
               random windows, turns, photos on the fly            (none without a fold)
mix            ``count`` samples an epoch, each drawn from entry   every entry's own validation set
               ``i`` of ``data.mix`` with probability w_i / sum w   (its ``validation``), put together
=============  ==================================================  =====================================

A mix (:class:`Mixture`) draws, per epoch, which entry each of its ``count`` positions comes
from, and walks through each entry's samples in shuffled passes; a real strip met again in
the same epoch gets another crop and symmetry (its pass number goes into the draw). All of it
follows from ``data.seed`` and the epoch, so a resumed fit sees the very same samples.

Des18 tiles are brought to ``train.resolution`` keeping the share of the surface a model sees
(:mod:`.fov`): training tiles scaled by ``resolution / 256`` before their crop, validation
tiles resized whole.

A ``materials`` source with a ``fold`` is also validated alone, as ``val_fold/``
(:func:`fold_validation_set`): materials the fit never trained on, of the same kind.

``data.real_validation`` names a second validation set of real materials (a Des18 folder or
shards), resized whole to the training resolution: :func:`real_validation_set`.

``data.generate: device`` makes the training batches with :func:`device_batch` in the
training process instead of a DataLoader's workers: procedural samples are computed on the
training device, the rest is read on the CPU and moved there.
"""

from __future__ import annotations

import dataclasses
import math
import operator
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset, Subset, default_collate

from svbrdf_models.errors import DataError

from . import Des18Folder, PhotoSettings, ProceduralMaterials

__all__ = [
    "DataSettings", "build_datasets", "section_datasets", "data_paths", "device_batch", "open_materials",
    "real_validation_set", "fold_validation_set", "set_epoch", "Mixture", "Resized",
]  # fmt: skip


class DataSettings(Protocol):
    """What the data sets are made from: the recipe's ``data`` section
    (:class:`svbrdf_train.recipe.DataSection`, a dataclass; ``data.setup(resolution)`` calls
    :func:`section_datasets`)."""

    source: str
    path: str | tuple[str, ...] | None
    count: int
    seed: int
    validation: int
    capture: str
    fold: str | None
    mix: tuple[dict, ...] | None
    balance: str
    albedo_prior: tuple[float, float] | None


def data_paths(path: str | tuple[str, ...] | list[str] | None) -> list[Path]:
    """``data.path`` as a list: one path, several, or the ``.h5`` files of a folder."""
    if path is None:
        return []
    items = [path] if isinstance(path, str) else list(path)
    out: list[Path] = []
    for item in items:
        p = Path(item).expanduser()
        if not p.exists():
            raise DataError(f"{p}: no such file or folder (data.path); give shard files or a Des18 folder")
        out.append(p)
    return out


def _split_off(data: Dataset, validation: int, what: str) -> tuple[Dataset, Dataset]:
    n = len(data)
    if validation >= n:
        raise DataError(
            f"{what}: {n} samples cannot give {validation} for validation and still leave some to train on; "
            "set data.validation lower"
        )
    return Subset(data, range(n - validation)), Subset(data, range(n - validation, n))


def build_datasets(recipe: Any) -> tuple[Dataset, Dataset]:
    """``(train, validation)`` for a :class:`~svbrdf_train.recipe.Recipe`, both at its
    ``train.resolution``: ``recipe.data.setup(recipe.train.resolution)``."""
    return section_datasets(recipe.data, recipe.train.resolution)


def section_datasets(d: DataSettings, res: int) -> tuple[Dataset, Dataset]:
    """``(train, validation)`` of the data section ``d``, both at ``res`` pixels.

    Raises:
        DataError: a missing or empty source, shards of another resolution, too few samples
            to hold out ``validation``; for a mix, starting with the entry (``data.mix[1] (des18)``).
    """
    if d.source != "mix":
        return _source_datasets(d, res)
    trains, vals, weights = [], [], []
    for i, entry in enumerate(d.mix or ()):
        part = dataclasses.replace(
            d,
            source=entry["source"],
            path=entry.get("path") or d.path,
            count=entry.get("count") or d.count,
            validation=d.validation if entry.get("validation") is None else entry["validation"],
            fold=entry.get("fold"),
            capture=entry.get("capture") or d.capture,
            mix=None,
            balance=d.balance if entry["source"] == "materials" else "none",
            albedo_prior=d.albedo_prior if entry["source"] == "materials" else None,
        )
        try:
            train, val = _source_datasets(part, res)
        except DataError as e:
            raise DataError(f"data.mix[{i}] ({entry['source']}): {e}") from None
        if len(train) == 0:
            raise DataError(f"data.mix[{i}] ({entry['source']}): no samples left to train on")
        trains.append(train)
        weights.append(float(entry["weight"]))
        if len(val):
            vals.append(val)
    val_set = ConcatDataset(vals) if vals else Subset(trains[0], [])
    return Mixture(trains, weights, d.count, seed=d.seed), val_set


def _source_datasets(d: DataSettings, res: int) -> tuple[Dataset, Dataset]:
    if d.source == "materials":
        return _strip_datasets(d, res)
    if d.source == "procedural":
        photo = PhotoSettings.preset(d.capture)
        return (
            ProceduralMaterials(d.count, res, seed=d.seed, photo=photo),
            ProceduralMaterials(d.validation, res, seed=d.seed + 1, photo=photo),
        )
    if not d.path:
        raise DataError(f"data.source {d.source} needs a path: give --data PATH, or --set data.path=PATH")
    paths = data_paths(d.path)
    if d.source == "shards":
        from .shards import ShardDataset

        files: list[Path] = []
        for p in paths:
            files += sorted(p.glob("*.h5")) if p.is_dir() else [p]
        if not files:
            raise DataError(f"{', '.join(map(str, paths))}: no .h5 shards there (data.path)")
        shards = ShardDataset(files)
        if shards.resolution != res:
            raise DataError(
                f"{files[0]}: shards hold {shards.resolution}x{shards.resolution} samples but the recipe "
                f"trains at {res}; set train.resolution={shards.resolution} "
                f"or make shards at --resolution {res}"
            )
        return _split_off(shards, d.validation, f"shards {files[0].parent}")
    if len(paths) != 1:
        raise DataError(f"data.source des18 reads one folder; got {len(paths)} paths")
    root = paths[0]
    train = Des18Folder(root, "train", crop=res, seed=d.seed, fov="resize")
    if (root / "testBlended").is_dir():
        return train, Des18Folder(root, "test", crop=res, fov="resize")
    val = Des18Folder(root, "train", crop=res, augment=False, random_crop=False, fov="resize")
    n = len(train)
    if d.validation >= n:
        raise DataError(
            f"{root}: {n} strips cannot give {d.validation} for validation and still leave some to train on; "
            "set data.validation lower, or add a testBlended/ folder"
        )
    return Subset(train, range(n - d.validation)), Subset(val, range(n - d.validation, n))


def set_epoch(data: Dataset, epoch: int) -> None:
    """``set_epoch`` of the data set under any Subsets, if it has one (random crops, mixes)."""
    while isinstance(data, Subset):
        data = data.dataset
    if hasattr(data, "set_epoch"):
        data.set_epoch(epoch)


class Mixture(Dataset):
    """``count`` samples an epoch from several data sets, sample ``k`` from ``sources[i]`` with
    probability ``weights[i] / sum(weights)``.

    :meth:`set_epoch` draws the epoch's assignment from ``(seed, epoch)``: which source each
    position reads, and which of its samples, walking through each source in shuffled passes.
    A source with ``set_epoch`` (Des18's random crops) is given a different one for each pass,
    so a strip met twice in an epoch is cropped and turned differently.
    """

    def __init__(self, sources: list[Dataset], weights: list[float], count: int, *, seed: int = 0):
        if len(sources) != len(weights) or not sources:
            raise ValueError("Mixture: one weight per source, and at least one source")
        if any(not (w > 0 and math.isfinite(w)) for w in weights):
            raise ValueError(f"Mixture: weights must be positive numbers, got {weights}")
        if any(len(s) == 0 for s in sources):
            raise ValueError("Mixture: every source needs samples")
        self.sources, self.count, self.seed = list(sources), int(count), int(seed)
        self.probabilities = torch.tensor(weights, dtype=torch.float64) / sum(weights)
        self.set_epoch(0)

    def __len__(self) -> int:
        return self.count

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        words = np.random.SeedSequence([self.seed, 0x6D6978, self.epoch]).generate_state(2, dtype=np.uint32)
        g = torch.Generator().manual_seed(int(words[0]) << 32 | int(words[1]))
        self.which = torch.multinomial(self.probabilities, self.count, replacement=True, generator=g)
        self.index = torch.zeros(self.count, dtype=torch.long)
        self.passes = torch.zeros(self.count, dtype=torch.long)
        for k, source in enumerate(self.sources):
            where = (self.which == k).nonzero().flatten()
            n = len(source)
            rounds = -(-len(where) // n)
            order = [torch.randperm(n, generator=g) for _ in range(rounds)]
            if order:
                self.index[where] = torch.cat(order)[: len(where)]
                self.passes[where] = torch.arange(len(where)) // n

    def locate(self, index: int) -> tuple[int, int, int]:
        """Where position ``index`` reads: ``(source, sample of it, the source's epoch)``."""
        epoch = self.epoch * (self.count + 1) + int(self.passes[index])
        return int(self.which[index]), int(self.index[index]), epoch

    def __getitem__(self, index: int) -> dict:
        k, local, epoch = self.locate(index)
        set_epoch(self.sources[k], epoch)
        return self.sources[k][local]


def device_batch(dataset: Dataset, indices: Sequence[int], device: torch.device | str) -> dict[str, Any]:
    """Samples ``indices`` of a training set as one batch on ``device``: ``{"input": (B, 3, R, R),
    "maps": (B, 10, R, R), "name": [B names]}``, the values a ``DataLoader`` over the same
    indices gives (default collate), without worker processes.

    ``data.generate: device`` makes training batches this way. Looks through the wrappers
    :func:`build_datasets` makes: a ``Subset`` maps the indices, a :class:`Mixture` reads
    each of its sources for the positions that come from it (under the epoch
    ``Mixture.__getitem__`` would set, and leaving the sources' epochs as a loop over the
    positions would) and puts the batch back in order.
    :class:`ProceduralMaterials` are computed on ``device`` (:meth:`ProceduralMaterials.batch`:
    on the CPU the very bytes of the DataLoader, elsewhere the same materials up to rounding,
    with the device's photo noise); anything else (shards, Des18 folders, :class:`Resized`)
    is read on the CPU item by item, collated and moved.
    """
    indices = [operator.index(i) for i in indices]
    if not indices:
        raise DataError("device_batch: expected at least one sample index")
    return _device_batch(dataset, indices, torch.device(device))


def _device_batch(data: Dataset, indices: list[int], device: torch.device) -> dict[str, Any]:
    if isinstance(data, Subset):
        return _device_batch(data.dataset, [data.indices[i] for i in indices], device)
    if isinstance(data, ProceduralMaterials):
        return data.batch(indices, device=device)
    from .real.strips import MaterialStrips

    if isinstance(data, MaterialStrips) and device.type != "cpu":  # the CPU keeps its exact path
        from .real.strip_batch import strip_batch

        return strip_batch(data, indices, device)
    if isinstance(data, Mixture):
        return _mixture_batch(data, indices, device)
    # What a DataLoader's fetcher does, then its default collate; then to the device.
    getitems = getattr(data, "__getitems__", None)
    items = getitems(indices) if getitems else [data[i] for i in indices]
    batch = default_collate(items)
    return {k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}


def _groups(keys: list) -> dict[Any, list[int]]:
    """The positions of each key, keys in order of first appearance."""
    out: dict[Any, list[int]] = {}
    for position, key in enumerate(keys):
        out.setdefault(key, []).append(position)
    return out


def _gather(parts: list[tuple[list[int], dict[str, Any]]], size: int) -> dict[str, Any]:
    """Batches of some positions each -> one batch of ``size`` in position order."""
    first = parts[0][1]
    out: dict[str, Any] = {}
    for key, value in first.items():
        if isinstance(value, torch.Tensor):
            t = value.new_empty((size, *value.shape[1:]))
            for positions, part in parts:
                if part[key].shape[1:] != value.shape[1:]:
                    raise DataError(
                        f"device_batch: {key} of shape {tuple(part[key].shape[1:])} and "
                        f"{tuple(value.shape[1:])} in one batch; every source must give one size"
                    )
                t[torch.tensor(positions, device=t.device)] = part[key]
            out[key] = t
        else:
            items: list[Any] = [None] * size
            for positions, part in parts:
                for p, v in zip(positions, part[key], strict=True):
                    items[p] = v
            out[key] = items
    return out


def _mixture_batch(mix: Mixture, indices: list[int], device: torch.device) -> dict[str, Any]:
    """:func:`device_batch` of a :class:`Mixture`: what ``mix[i]`` reads, source by source."""
    which, local, epoch = (list(column) for column in zip(*map(mix.locate, indices), strict=True))
    parts = []
    for k, positions in _groups(which).items():
        source = mix.sources[k]
        # A source with epochs (Des18's crops) is read pass by pass, each under its epoch;
        # one without, all at once.
        key = (lambda p: epoch[p]) if _has_epochs(source) else (lambda p: None)
        for e, group in _groups([key(p) for p in positions]).items():
            members = [positions[g] for g in group]
            if e is not None:
                set_epoch(source, e)
            parts.append((members, _device_batch(source, [local[p] for p in members], device)))
    # Leave every source at the epoch a loop over the positions would have left it at.
    last = {k: p for p, k in enumerate(which)}
    for k, p in sorted(last.items(), key=lambda item: item[1]):
        set_epoch(mix.sources[k], epoch[p])
    return _gather(parts, len(indices))


def _has_epochs(data: Dataset) -> bool:
    while isinstance(data, Subset):
        data = data.dataset
    return hasattr(data, "set_epoch")


class Resized(Dataset):
    """Every sample of ``data`` resized whole to ``resolution`` (field of view kept)."""

    def __init__(self, data: Dataset, resolution: int):
        self.data, self.resolution = data, resolution

    def __len__(self) -> int:
        return len(self.data)

    def __getitem__(self, index: int) -> dict:
        from .fov import resize_sample

        sample = self.data[index]
        if min(sample["input"].shape[-2:]) < self.resolution:
            raise DataError(
                f"{sample.get('name', index)}: {tuple(sample['input'].shape[-2:])} pixels, smaller than "
                f"the training resolution {self.resolution}; real validation needs samples at least "
                "that large"
            )
        return resize_sample(sample, self.resolution)


def open_materials(path: str | Path, role: str) -> tuple[Dataset, str]:
    """Materials with ground truth at their own size: a Des18 folder or ``.h5`` shards, and a
    description. The first sample is decoded, so a folder of the wrong kind is found now.

    Raises:
        DataError: a path that is missing, empty, or neither a Des18 folder nor shards, or
            whose first sample cannot be read; one line starting with ``role`` and the path.
    """
    p = Path(path).expanduser()
    where = f"{role} {p}"
    if not p.exists():
        raise DataError(f"{where}: no such file or folder; give a Des18 folder or .h5 shards")
    shards = [p] if p.suffix == ".h5" and p.is_file() else sorted(p.glob("*.h5")) if p.is_dir() else []
    strips = _strip_materials(p, shards, role)
    if strips is not None:
        return strips
    if shards:
        from .shards import ShardDataset

        data: Dataset = ShardDataset(shards)
        what = f"{len(data)} samples of {p}"
    elif p.is_dir():
        try:
            data = Des18Folder(p, "test", crop=None)
        except DataError as e:  # an empty folder, or one of other files; the message names it
            raise DataError(f"{role} {e}") from None
        what = f"{len(data)} Des18 samples of {data.folder}"
    else:
        raise DataError(f"{where}: not a Des18 folder nor .h5 shards")
    if len(data) == 0:
        raise DataError(f"{where}: holds no samples")
    try:
        data[0]
    except Exception as e:  # MapFileError, DataError, h5py's errors: all name the file
        raise DataError(f"{where}: cannot be read as materials with ground truth: {e}") from None
    return data, what


def real_validation_set(path: str | None, resolution: int) -> tuple[Dataset, str] | None:
    """``(dataset, description)`` of ``data.real_validation`` resized whole to ``resolution``, or
    None when it is not set (errors: :func:`open_materials`)."""
    if path is None:
        return None
    data, what = open_materials(path, "data.real_validation")
    return Resized(data, resolution), f"{what} (resized whole to {resolution} px)"


def _bank(path):
    """The materials of a strip folder or shard, decoded once per process and path."""
    from .real.strip_bank import MaterialBank

    p = Path(path).expanduser().resolve()
    stamp = p.stat().st_mtime_ns if p.exists() else 0
    hit = _BANKS.get(p)
    if hit is None or hit[0] != stamp:
        hit = _BANKS[p] = (stamp, MaterialBank.open(p))
    return hit[1]


_BANKS: dict = {}


def _strip_datasets(d: DataSettings, res: int) -> tuple[Dataset, Dataset]:
    """``(train, held-out fold)`` of a ``materials`` source (:mod:`.real.strips`)."""
    from .real.strips import MaterialStrips, fold_split

    if not d.path:
        raise DataError("data.source materials needs a path: give --data FOLDER (strips) or a strip shard")
    paths = data_paths(d.path)
    if len(paths) != 1:
        raise DataError(f"data.source materials reads one folder or strip shard; got {len(paths)} paths")
    bank = _bank(paths[0])
    train, held = fold_split(bank.names, d.fold, str(paths[0]))
    photo = PhotoSettings.preset(d.capture)
    train_set = MaterialStrips(bank.select(train), d.count, res, seed=d.seed, photo=photo,
                               balance=d.balance, albedo_prior=d.albedo_prior)
    if not held:
        return train_set, Subset(train_set, [])
    val = bank.select(held)
    return train_set, MaterialStrips(val, len(val), res, seed=d.seed + 1, photo=photo, augment=False)


def fold_validation_set(d: DataSettings, res: int) -> tuple[Dataset, str] | None:
    """``(dataset, description)`` of the held-out fold of the ``materials`` source (or the first
    mix entry) that has a ``fold``, photographed under that entry's capture, logged as
    ``val_fold/``; None when none has."""
    entries = list(d.mix or ()) if d.source == "mix" else [{"source": d.source, "fold": d.fold}]
    for entry in entries:
        if entry.get("source") == "materials" and entry.get("fold"):
            part = dataclasses.replace(d, source="materials", path=entry.get("path") or d.path,
                                       fold=entry["fold"], capture=entry.get("capture") or d.capture,
                                       mix=None)  # fmt: skip
            _, held = _strip_datasets(part, res)
            names = ", ".join(s.removeprefix("strip:") for s in held.bank.names[:4])
            return held, f"{len(held)} held-out materials (fold {entry['fold']}: {names}, ...)"
    return None


def _strip_materials(p: Path, shards: list[Path], role: str) -> tuple[Dataset, str] | None:
    """Map-only strips (a strip folder or one strip shard) as materials with ground truth: each
    whole tile under a fixed phone photo (:class:`.real.strips.MaterialStrips`); else None."""
    from .real.strip_bank import STRIP_FORMAT, is_strip_folder
    from .real.strips import MaterialStrips

    if len(shards) == 1 and shards[0] == p:
        import h5py

        try:
            with h5py.File(p, "r") as f:
                if f.attrs.get("format") != STRIP_FORMAT:
                    return None
        except OSError:  # damaged or not HDF5: the shard reader says so, naming the file
            return None
    elif not is_strip_folder(p):
        return None
    try:
        bank = _bank(p)
    except DataError as e:
        raise DataError(f"{role} {e}") from None
    data = MaterialStrips(
        bank, len(bank), bank.tile, seed=1, photo=PhotoSettings.preset("phone"), augment=False
    )
    return data, f"{len(bank)} material strips of {p} (photographed under the phone capture)"
