"""The test set every model of a benchmark is judged on.

- default: ``count`` procedural materials from :data:`~svbrdf_bench.presets.TEST_SEED`, a seed
  no training or validation set uses, made at the models' resolution;
- a Des18 folder (its ``testBlended/`` if it has one): whole tiles resized to the models'
  resolution;
- HDF5 shards (``.h5`` files or a folder of them): samples larger than the models resized.

:attr:`TestSet.groups` gives each real test sample its source materials
(:func:`svbrdf_train.data.real.materials.group_samples`: ``--group-by auto|des18|file``): the report
averages per material, not per strip, so a material shown by 3 strips weighs as much as one shown
by 1, and resamples materials in its bootstrap intervals. The procedural test set has none (each
image is its own material).

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
        #: The name of each sample, in order (empty for the procedural test set).
        self.sample_names: list[str] = []
        #: The side in px each sample is stored at, before any resizing, in order.
        self.sides: list[int] = []
        #: The source materials of each sample, in order; None: each image is its own.
        self.groups: list[tuple[str, ...]] | None = None
        #: How the samples were grouped: ``des18``, ``file``, or ``image`` (procedural).
        self.group_by = "image"

    def grouping_words(self) -> str:
        """How many samples and materials the report's means are over, in words."""
        if self.groups is None:
            return f"{len(self)} images, each its own material"
        materials = len({m for g in self.groups for m in g})
        how = "a Des18 strip counts for both its materials" if self.group_by == "des18" else "one per file"
        return f"{len(self)} strips of {materials} materials ({how})"

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
            from svbrdf_train import resize_sample

            sample = resize_sample(sample, r)
        return {"input": sample["input"], "maps": sample["maps"], "name": sample["name"], "side": h}


def test_set(path: str | Path | None, resolution: int, count: int, group_by: str = "auto") -> TestSet:
    """The benchmark's test set (see the module doc); ``group_by``: how real samples are grouped
    into materials (``auto``, ``des18``, ``file``)."""
    from svbrdf_train import GROUP_BY, group_samples

    if group_by not in GROUP_BY:
        raise BenchError(f"--group-by {group_by}: choose one of {', '.join(GROUP_BY)}")
    if path is None:
        from svbrdf_train import ProceduralMaterials

        if group_by == "des18":
            raise BenchError(
                "--group-by des18 groups the strips of a Des18 folder by the materials their names give; "
                "give that folder as --test-data (procedural test images are each a material of their own)"
            )
        data = ProceduralMaterials(count, resolution, seed=TEST_SEED)
        test = TestSet(data, resolution, f"{count} procedural materials (seed {TEST_SEED})")
        test.sides = [resolution] * count
        return test
    from svbrdf_models import DataError
    from svbrdf_train import open_materials

    try:
        data, what = open_materials(path, "--test-data")
    except DataError as e:
        raise BenchError(str(e)) from None
    test = TestSet(data, resolution, f"{what} (whole images resized to {resolution} px)")

    def grouped(names: list[str]) -> None:
        try:
            test.group_by, test.groups = group_samples(names, group_by)
        except DataError as e:
            raise BenchError(f"--test-data {path}: --group-by {group_by}: {e}") from None

    files = getattr(data, "files", None)
    if files is not None:  # a folder: names are checked before any strip is decoded
        grouped([Path(f).name for f in files])
    # Every sample is read once now, before any training: a damaged chunk of a shard, a strip
    # that is not square or smaller than the models is refused up front, not after an hour.
    for i in range(len(test)):
        try:
            sample = test[i]
            test.sample_names.append(str(sample["name"]))
            test.sides.append(int(sample["side"]))
            test.names.add(test.sample_names[-1])
        except BenchError:
            raise
        except Exception as e:  # DataError, MapFileError, h5py's checksum errors: name the input
            first = str(e).strip().splitlines()[0][:200] if str(e).strip() else type(e).__name__
            raise BenchError(f"--test-data {path}: sample {i} cannot be read ({first})") from None
    test.names |= {Path(p).name for p in getattr(data, "paths", ())}  # shard files
    grouped(test.sample_names)  # the names the samples carry (of shards too), in order
    return test
