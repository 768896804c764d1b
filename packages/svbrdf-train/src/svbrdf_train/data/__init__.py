"""Training data: procedural materials, real data set readers and HDF5 shards.

Three rooms, each importing only the shared modules here, never one another but for the
strip shards of ``real``, which are ``shards``' format:

- :mod:`.procedural`: materials drawn from seeded families, with nothing to download;
- :mod:`.real`: the Des18 data set and material strips (measured or scanned maps);
- :mod:`.shards`: samples stored in HDF5 files, written once and read by many workers.

Shared by them: the sample layout (:mod:`.sample`), the seeded streams (:mod:`.seeds`), the
simulated phone photo of a sample (:mod:`.simulated_photo`, with its JPEG round trip in
:mod:`.jpeg`), resizing a sample (:mod:`.fov`), folders of photos without maps
(:mod:`.photos`), statistics and contact sheets of data sets (:mod:`.stats`, :mod:`.sheet`),
and the data sets of one fit (:mod:`.fitdata`, above the three rooms).

Every data set returns the sample dict of :mod:`svbrdf_train.data.sample` (``input``,
``maps``, ``name``), so DataLoader's default collate works on all of them::

    from svbrdf_train.data import ProceduralMaterials, Des18Folder, PhotoFolder, ShardDataset
    train = ProceduralMaterials(count=10_000, resolution=256, seed=0)   # no download needed
    test = Des18Folder("DATA/des18-dev", split="test")        # centre 256 crops
    photos = PhotoFolder("my-photos/", encoding="srgb", size=256)       # no ground truth
    shards = ShardDataset(["train-0.h5", "train-1.h5"])                # written by `data make`

The shards room (and h5py with it) is imported on first use of a shard name.
"""

from __future__ import annotations

import importlib

from .photos import PhotoFolder
from .procedural import FAMILIES, GENERATOR_VERSION, ProceduralMaterials, material, materials
from .real.des18 import Des18Folder, dihedral, dihedral_image
from .sample import batch_svbrdf
from .simulated_photo import PhotoSettings, photo_scene

_SHARD_NAMES = ("ShardDataset", "ShardWriter", "ShardInfo", "inspect_shard", "write_shard")


def __getattr__(name: str):
    if name in _SHARD_NAMES:
        return getattr(importlib.import_module(".shards", __name__), name)
    if name == "contact_sheet":
        return importlib.import_module(".sheet", __name__).contact_sheet
    raise AttributeError(f"module 'svbrdf_train.data' has no attribute {name!r}")


__all__ = [
    "FAMILIES",
    "GENERATOR_VERSION",
    "Des18Folder",
    "PhotoFolder",
    "PhotoSettings",
    "ProceduralMaterials",
    "batch_svbrdf",
    "dihedral",
    "dihedral_image",
    "material",
    "materials",
    "photo_scene",
    "contact_sheet",
    *_SHARD_NAMES,
]
