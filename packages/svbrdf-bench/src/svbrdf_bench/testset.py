"""The test set every model of a benchmark is judged on.

- default: ``count`` procedural materials from :data:`~svbrdf_bench.presets.TEST_SEED`, a seed
  no training or validation set uses;
- a Des18 folder (its ``testBlended/`` if it has one), centre crops;
- HDF5 shards (``.h5`` files or a folder of them), centre crops when larger.
"""

from __future__ import annotations

from pathlib import Path

from torch.utils.data import Dataset

from .errors import BenchError
from .presets import TEST_SEED

__all__ = ["TestSet", "test_set"]


class TestSet(Dataset):
    """Samples of another data set, centre-cropped to ``resolution``; says where they came from."""

    __test__ = False  # not a pytest class

    def __init__(self, data: Dataset, resolution: int, description: str):
        self.data, self.resolution, self.description = data, resolution, description

    def __len__(self) -> int:
        return len(self.data)

    def __getitem__(self, index: int) -> dict:
        sample = self.data[index]
        h, w = sample["input"].shape[-2:]
        r = self.resolution
        if min(h, w) < r:
            raise BenchError(
                f"{self.description}: sample {index} is {h}x{w}, smaller than the {r} px the models run at"
            )
        top, left = (h - r) // 2, (w - r) // 2
        return {
            "input": sample["input"][:, top : top + r, left : left + r],
            "maps": sample["maps"][:, top : top + r, left : left + r],
            "name": sample["name"],
        }


def test_set(path: str | Path | None, resolution: int, count: int) -> TestSet:
    """The benchmark's test set (see the module doc)."""
    if path is None:
        from svbrdf_train.data import ProceduralMaterials

        data = ProceduralMaterials(count, resolution, seed=TEST_SEED)
        return TestSet(data, resolution, f"{count} procedural materials (seed {TEST_SEED})")
    p = Path(path).expanduser()
    if not p.exists():
        raise BenchError(f"--test-data {p}: no such file or folder; give a Des18 folder or .h5 shards")
    shards = [p] if p.suffix == ".h5" else sorted(p.glob("*.h5")) if p.is_dir() else []
    if shards:
        from svbrdf_train.data.shards import ShardDataset

        data = ShardDataset(shards)
        what = f"{len(data)} samples of {p}"
    elif p.is_dir():
        from svbrdf_train.data import Des18Folder

        data = Des18Folder(p, "test", crop=None)
        what = f"{len(data)} Des18 samples of {data.folder}"
    else:
        raise BenchError(f"--test-data {p}: not a Des18 folder nor .h5 shards")
    if len(data) == 0:
        raise BenchError(f"--test-data {p}: holds no samples")
    return TestSet(data, resolution, what)
