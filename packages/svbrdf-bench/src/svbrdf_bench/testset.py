"""The test set every model of a benchmark is judged on.

- default: ``count`` procedural materials from :data:`~svbrdf_bench.presets.TEST_SEED`, a seed
  no training or validation set uses, made at the models' resolution;
- a Des18 folder (its ``testBlended/`` if it has one): whole tiles resized to the models'
  resolution;
- HDF5 shards (``.h5`` files or a folder of them): samples larger than the models resized.

:attr:`TestSet.names` holds the names of the test files (Des18 strips, and for shards the shard
files and the names their samples carry): a reference model whose provenance lists one of them
among its training strips is refused (:mod:`svbrdf_bench.references`).

Resizing, not cropping: an image always covers the surface ``[-1, 1]^2``, and a model must see
test images at the field of view it was trained on. The centre 128 px of a 288 px Des18 tile
show 44% of the surface's width and a flash highlight more than twice as large as any the model
trained on. :func:`svbrdf_train.data.fov.resize_sample` brings a sample down with the area filter
(photo and maps alike, normals renormalised), so the resized maps still re-render the resized
photo under the flash of the full-size photo.
"""

from __future__ import annotations

from pathlib import Path

from torch.utils.data import Dataset

from .errors import BenchError
from .presets import TEST_SEED

__all__ = ["TestSet", "test_set"]


class TestSet(Dataset):
    """Samples of another data set, resized to ``resolution`` when larger; says where they came from."""

    __test__ = False  # not a pytest class

    def __init__(self, data: Dataset, resolution: int, description: str):
        self.data, self.resolution, self.description = data, resolution, description
        #: Names of the real files tested on (empty for the procedural test set).
        self.names: set[str] = set()

    def __len__(self) -> int:
        return len(self.data)

    def __getitem__(self, index: int) -> dict:
        sample = self.data[index]
        h, w = sample["input"].shape[-2:]
        r = self.resolution
        if h != w:
            raise BenchError(
                f"{self.description}: sample {index} is {h}x{w}; test samples must be square images "
                "of the whole surface"
            )
        if h < r:
            raise BenchError(
                f"{self.description}: sample {index} is {h}x{w}, smaller than the {r} px the models run at"
            )
        if h != r:
            from svbrdf_train.data.fov import resize_sample

            sample = resize_sample(sample, r)
        return {"input": sample["input"], "maps": sample["maps"], "name": sample["name"]}


def test_set(path: str | Path | None, resolution: int, count: int) -> TestSet:
    """The benchmark's test set (see the module doc)."""
    if path is None:
        from svbrdf_train.data import ProceduralMaterials

        data = ProceduralMaterials(count, resolution, seed=TEST_SEED)
        return TestSet(data, resolution, f"{count} procedural materials (seed {TEST_SEED})")
    from svbrdf_train.errors import DataError
    from svbrdf_train.fitdata import open_materials

    try:
        data, what = open_materials(path, "--test-data")
    except DataError as e:
        raise BenchError(str(e)) from None
    test = TestSet(data, resolution, f"{what} (whole images resized to {resolution} px)")
    # Every sample is read once now, before any training: a damaged chunk of a shard, a strip
    # that is not square or smaller than the models is refused up front, not after an hour.
    for i in range(len(test)):
        try:
            test.names.add(str(test[i]["name"]))
        except BenchError:
            raise
        except Exception as e:  # DataError, MapFileError, h5py's checksum errors: name the input
            first = str(e).strip().splitlines()[0][:200] if str(e).strip() else type(e).__name__
            raise BenchError(f"--test-data {path}: sample {i} cannot be read ({first})") from None
    test.names |= {Path(p).name for p in getattr(data, "paths", ())}  # shard files
    return test
