"""HDF5 shards: round trips, provenance, damaged and inconsistent files, workers and samplers."""

from __future__ import annotations

import hashlib
import pickle

import h5py
import pytest
import torch
from torch.utils.data import DataLoader, DistributedSampler

from conftest import random_svbrdf
from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF
from svbrdf_train.data.shards import (
    FORMAT_VERSION,
    ShardDataset,
    ShardWriter,
    inspect_shard,
    write_shard,
)
from svbrdf_train.errors import ShardError


def _batch(count: int, size: int = 16, seed: int = 0, prefix: str = "s") -> dict:
    maps = random_svbrdf(count, size, seed=seed)
    photo = torch.rand(count, 3, size, size, generator=torch.Generator().manual_seed(seed + 1000))
    return {"input": photo, "maps": maps.pack(), "name": [f"{prefix}{i}" for i in range(count)]}


def _shard(path, count=4, size=16, seed=0, bits=8, prefix="s", attrs=None):
    batch = _batch(count, size, seed, prefix)
    write_shard(path, [batch], size, bits=bits, attrs=attrs)
    return batch


# -- round trips ------------------------------------------------------------------------------


@pytest.mark.parametrize("bits", [8, 16])
def test_round_trip_within_quantisation(tmp_path, bits):
    step = 1 / (2**bits - 1)
    written = _shard(tmp_path / "a.h5", count=5, bits=bits)
    data = ShardDataset(tmp_path / "a.h5")
    assert len(data) == 5 and data.resolution == 16
    for i in range(5):
        sample = data[i]
        assert sample["name"] == f"s{i}"
        assert sample["input"].dtype == sample["maps"].dtype == torch.float32
        assert sample["input"].shape == (3, 16, 16) and sample["maps"].shape == (10, 16, 16)
        assert float((sample["input"] - written["input"][i]).abs().max()) <= step / 2 + 1e-6
        got, want = sample["maps"], written["maps"][i]
        assert float((got[3:] - want[3:]).abs().max()) <= step / 2 + 1e-6
        # (n + 1) / 2 quantised, decoded by 2x - 1 (one step), then re-normalised.
        assert float((got[:3] - want[:3]).abs().max()) <= 2 * step
        assert torch.allclose(got[:3].norm(dim=0), torch.ones(16, 16), atol=1e-5)
    SVBRDF.unpack(torch.stack([data[i]["maps"] for i in range(5)]))  # valid ranges


def test_sixteen_bits_are_finer_than_eight(tmp_path):
    written = _shard(tmp_path / "a8.h5", bits=8)
    _shard(tmp_path / "a16.h5", bits=16)
    err = {}
    for bits in (8, 16):
        sample = ShardDataset(tmp_path / f"a{bits}.h5")[0]
        err[bits] = float((sample["maps"][3:] - written["maps"][0, 3:]).abs().max())
    assert err[16] < err[8] / 100


def test_append_one_by_one_equals_extend(tmp_path):
    batch = _batch(3)
    write_shard(tmp_path / "batched.h5", [batch], 16)
    with ShardWriter(tmp_path / "single.h5", 16) as shard:
        for i in range(3):
            shard.append({"input": batch["input"][i], "maps": batch["maps"][i], "name": batch["name"][i]})
    assert shard.count == 3
    a, b = ShardDataset(tmp_path / "batched.h5"), ShardDataset(tmp_path / "single.h5")
    for i in range(3):
        assert torch.equal(a[i]["maps"], b[i]["maps"]) and a[i]["name"] == b[i]["name"]


def test_same_samples_give_identical_bytes(tmp_path):
    digests = []
    for name in ("one.h5", "two.h5"):
        _shard(tmp_path / name, attrs={"seed": 3})
        digests.append(hashlib.sha256((tmp_path / name).read_bytes()).hexdigest())
    assert digests[0] == digests[1]


def test_several_shards_read_as_one(tmp_path):
    first = _shard(tmp_path / "a.h5", count=3, prefix="a")
    second = _shard(tmp_path / "b.h5", count=2, seed=5, prefix="b", bits=16)  # depths may differ
    data = ShardDataset([tmp_path / "a.h5", str(tmp_path / "b.h5")])
    assert len(data) == 5
    assert [data[i]["name"] for i in range(5)] == ["a0", "a1", "a2", "b0", "b1"]
    assert data.locate(3) == (1, 0) and data.locate(-1) == (1, 1)
    assert float((data[4]["maps"][3:] - second["maps"][1, 3:]).abs().max()) < 1e-4
    assert float((data[0]["maps"][3:] - first["maps"][0, 3:]).abs().max()) < 1 / 255
    with pytest.raises(IndexError):
        data[5]


# -- provenance -------------------------------------------------------------------------------


def test_attributes_record_provenance(tmp_path):
    attrs = {
        "source": "procedural",
        "generator_version": "1",
        "seed": 7,
        "families": ["stone", "wood"],
        "mix": 0.25,
        "photo": {"fov": [40.0, 70.0]},
        "skipped": None,
    }
    _shard(tmp_path / "a.h5", count=3, bits=16, attrs=attrs)
    info = inspect_shard(tmp_path / "a.h5")
    assert (info.count, info.resolution, info.bits) == (3, 16, 16)
    a = info.attrs
    assert a["format"] == "svbrdf-shard" and a["format_version"] == FORMAT_VERSION
    assert a["complete"] is True and a["count"] == 3
    assert a["source"] == "procedural" and a["generator_version"] == "1" and a["seed"] == 7
    assert a["families"] == ["stone", "wood"] and a["mix"] == 0.25
    assert a["photo"] == '{"fov": [40.0, 70.0]}'
    assert "skipped" not in a
    assert "svbrdf-train" in a["created_by"] and "h5py" in a["created_by"]
    with h5py.File(tmp_path / "a.h5") as f:
        ds = f["diffuse"]
        assert ds.chunks == (1, 16, 16, 3) and ds.compression == "gzip" and ds.fletcher32
        assert ds.dtype == "uint16"


def test_writer_refuses_reserved_attributes(tmp_path):
    with pytest.raises(DataError, match="count"):
        ShardWriter(tmp_path / "a.h5", 16, attrs={"count": 3})
    assert list(tmp_path.iterdir()) == []


# -- writing fails cleanly --------------------------------------------------------------------


@pytest.mark.parametrize("interruption", [RuntimeError, KeyboardInterrupt])
def test_interrupted_write_leaves_nothing(tmp_path, interruption):
    with pytest.raises(interruption):
        with ShardWriter(tmp_path / "a.h5", 16) as shard:
            shard.extend(_batch(2))
            raise interruption()
    assert list(tmp_path.iterdir()) == []


def test_failed_overwrite_keeps_the_old_shard(tmp_path):
    _shard(tmp_path / "a.h5", count=2)
    before = (tmp_path / "a.h5").read_bytes()
    with pytest.raises(DataError, match="already exists"):
        ShardWriter(tmp_path / "a.h5", 16)
    with pytest.raises(DataError, match="NaN"):
        with ShardWriter(tmp_path / "a.h5", 16, overwrite=True) as shard:
            bad = _batch(2)
            bad["input"][1, 0, 3, 3] = float("nan")
            shard.extend(bad)
    assert (tmp_path / "a.h5").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]


def test_writer_checks_what_it_is_given(tmp_path):
    with ShardWriter(tmp_path / "a.h5", 16) as shard:
        with pytest.raises(DataError, match=r"'maps' is \(2, 10, 8, 8\), expected \(2, 10, 16, 16\)"):
            shard.extend(_batch(2, size=8) | {"input": torch.rand(2, 3, 16, 16)})
        with pytest.raises(DataError, match="no maps"):
            shard.extend({"input": torch.rand(1, 3, 16, 16), "name": ["photo"]})
        shard.extend(_batch(1))
    assert inspect_shard(tmp_path / "a.h5").count == 1
    with pytest.raises(DataError, match="bits"):
        ShardWriter(tmp_path / "b.h5", 16, bits=12)


# -- damaged and inconsistent shards ----------------------------------------------------------


def test_truncated_shard_names_the_file(tmp_path):
    path = tmp_path / "cut.h5"
    _shard(path, count=4)
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.truncate(size // 2)
    with pytest.raises(ShardError, match="truncated or corrupted") as err:
        ShardDataset(path)
    assert str(path) in str(err.value)


def test_corrupted_chunk_names_the_file_and_the_sample(tmp_path):
    path = tmp_path / "bad.h5"
    _shard(path, count=4)
    with h5py.File(path) as f:
        chunk = f["specular"].id.get_chunk_info(2)  # sample 2's chunk: where its bytes lie
    with open(path, "r+b") as f:
        f.seek(chunk.byte_offset + chunk.size // 2)
        f.write(bytes(8))
    data = ShardDataset(path)  # attributes and shapes are intact
    data[1], data[3]  # other samples still read
    with pytest.raises(ShardError, match=r"bad\.h5: sample 2 cannot be read"):
        data[2]


def test_missing_map_names_it(tmp_path):
    path = tmp_path / "a.h5"
    _shard(path)
    with h5py.File(path, "r+") as f:
        del f["roughness"]
    with pytest.raises(ShardError, match=r"a\.h5: missing dataset\(s\) roughness"):
        ShardDataset(path)


def test_count_disagreeing_with_a_dataset(tmp_path):
    path = tmp_path / "a.h5"
    _shard(path, count=4)
    with h5py.File(path, "r+") as f:
        f["normal"].resize(3, axis=0)
    with pytest.raises(ShardError, match=r"'normal' has shape \(3, 16, 16, 3\), expected \(4, 16, 16, 3\)"):
        ShardDataset(path)


def test_incomplete_shard(tmp_path):
    path = tmp_path / "a.h5"
    _shard(path)
    with h5py.File(path, "r+") as f:
        f.attrs["complete"] = False
    with pytest.raises(ShardError, match="incomplete"):
        ShardDataset(path)


def test_not_a_shard_and_newer_format(tmp_path):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = [1, 2, 3]
    with pytest.raises(ShardError, match="not an svbrdf shard"):
        ShardDataset(tmp_path / "other.h5")
    _shard(tmp_path / "new.h5")
    with h5py.File(tmp_path / "new.h5", "r+") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(ShardError, match="upgrade svbrdf-train"):
        ShardDataset(tmp_path / "new.h5")
    with pytest.raises(ShardError, match="does not exist"):
        ShardDataset(tmp_path / "missing.h5")
    with pytest.raises(ShardError, match="no shard"):
        ShardDataset([])


def test_resolution_mismatch_names_both_files(tmp_path):
    _shard(tmp_path / "small.h5", size=16)
    _shard(tmp_path / "large.h5", size=24)
    with pytest.raises(ShardError, match="share one resolution") as err:
        ShardDataset([tmp_path / "small.h5", tmp_path / "large.h5"])
    assert "small.h5" in str(err.value) and "large.h5" in str(err.value)
    assert "16x16" in str(err.value) and "24x24" in str(err.value)


# -- processes --------------------------------------------------------------------------------


def test_pickles_without_open_files(tmp_path):
    _shard(tmp_path / "a.h5")
    data = ShardDataset(tmp_path / "a.h5")
    first = data[0]
    copy = pickle.loads(pickle.dumps(data))
    assert torch.equal(copy[0]["maps"], first["maps"])
    data.close()
    assert torch.equal(data[0]["input"], first["input"])  # reopens


def test_dataloader_with_two_workers_reads_what_indexing_reads(tmp_path):
    _shard(tmp_path / "a.h5", count=5, prefix="a")
    _shard(tmp_path / "b.h5", count=4, seed=9, prefix="b")
    data = ShardDataset([tmp_path / "a.h5", tmp_path / "b.h5"])
    direct = [data[i] for i in range(len(data))]  # opens files in this process before forking
    loader = DataLoader(data, batch_size=2, num_workers=2)
    names, maps = [], []
    for batch in loader:
        names += batch["name"]
        maps.append(batch["maps"])
    assert names == [s["name"] for s in direct]
    assert torch.equal(torch.cat(maps), torch.stack([s["maps"] for s in direct]))


def test_dataloader_with_spawned_workers(tmp_path):
    _shard(tmp_path / "a.h5", count=4)
    data = ShardDataset(tmp_path / "a.h5")
    loader = DataLoader(data, batch_size=4, num_workers=2, multiprocessing_context="spawn")
    (batch,) = list(loader)
    assert torch.equal(batch["input"], torch.stack([data[i]["input"] for i in range(4)]))


def test_distributed_sampler_splits_all_samples_between_ranks(tmp_path):
    _shard(tmp_path / "a.h5", count=5)
    _shard(tmp_path / "b.h5", count=4, seed=3, prefix="b")
    data = ShardDataset([tmp_path / "a.h5", tmp_path / "b.h5"])
    ranks = [DistributedSampler(data, num_replicas=2, rank=r, shuffle=True, seed=1) for r in (0, 1)]
    indices = [list(s) for s in ranks]
    assert len(indices[0]) == len(indices[1]) == 5  # 9 samples, one repeated to even out
    assert set(indices[0]) | set(indices[1]) == set(range(9))
    names = {data[i]["name"] for i in indices[0] + indices[1]}
    assert len(names) == 9
