"""The training and validation sets of a recipe's ``data`` section.

=============  ==================================================  =====================================
source         training set                                        validation set (fixed, held out)
=============  ==================================================  =====================================
procedural     ``count`` materials of ``seed``                     ``validation`` materials of
                                                                   ``seed + 1`` (never the same ones)
shards         every sample of the files but the last              the last ``validation`` samples
               ``validation``
des18          the folder's ``trainBlended/`` (or the strips),     ``testBlended/`` when there is one,
               random crops and the 8 symmetries                   else the last ``validation`` strips;
                                                                   centre crops
=============  ==================================================  =====================================
"""

from __future__ import annotations

from pathlib import Path

from torch.utils.data import Dataset, Subset

from .data import Des18Folder, ProceduralMaterials
from .errors import DataError
from .recipe import Recipe

__all__ = ["build_datasets", "data_paths"]


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


def build_datasets(recipe: Recipe) -> tuple[Dataset, Dataset]:
    """``(train, validation)`` for the recipe, both at ``train.resolution``."""
    d, res = recipe.data, recipe.train.resolution
    if d.source == "procedural":
        return (
            ProceduralMaterials(d.count, res, seed=d.seed),
            ProceduralMaterials(d.validation, res, seed=d.seed + 1),
        )
    paths = data_paths(d.path)
    if d.source == "shards":
        from .data.shards import ShardDataset

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
    train = Des18Folder(root, "train", crop=res, seed=d.seed)
    if (root / "testBlended").is_dir():
        return train, Des18Folder(root, "test", crop=res)
    val = Des18Folder(root, "train", crop=res, augment=False, random_crop=False)
    n = len(train)
    if d.validation >= n:
        raise DataError(
            f"{root}: {n} strips cannot give {d.validation} for validation and still leave some to train on; "
            "set data.validation lower, or add a testBlended/ folder"
        )
    return Subset(train, range(n - d.validation)), Subset(val, range(n - d.validation, n))
