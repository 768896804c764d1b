"""HDF5 shards: training samples written once (``svbrdf-train data make`` and ``data import``)
and read many times by the fit's DataLoader workers.

- :mod:`.store`: writing a shard (:class:`ShardWriter`, :func:`write_shard`) and reading a set
  of them (:class:`ShardDataset`); the layout of a shard is described there;
- :mod:`.format`: the format's name, version, datasets and attributes, and the check of a file
  (:func:`inspect_shard`), which the strip shards of :mod:`svbrdf_train.data.real` share.

Importing it imports h5py: :mod:`svbrdf_train.data` imports it on first use of a shard name.
"""

from __future__ import annotations

from .format import COMPRESSION, FORMAT, FORMAT_VERSION, SHARD_DATASETS, ShardInfo, inspect_shard
from .store import ShardDataset, ShardWriter, write_shard

__all__ = [
    "COMPRESSION",
    "FORMAT",
    "FORMAT_VERSION",
    "SHARD_DATASETS",
    "ShardDataset",
    "ShardInfo",
    "ShardWriter",
    "inspect_shard",
    "write_shard",
]
