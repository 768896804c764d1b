"""The benchmark's test set: fixed procedural images by default, Des18 folders and shards when given."""

from __future__ import annotations

import pytest
import torch

from svbrdf_bench.errors import BenchError
from svbrdf_bench.presets import TEST_SEED
from svbrdf_bench.testset import test_set as make_test_set
from svbrdf_train.data import ProceduralMaterials


def test_default_is_fixed_and_apart_from_training_data():
    a, b = make_test_set(None, 32, 3), make_test_set(None, 32, 3)
    assert len(a) == 3 and a[0]["input"].shape == (3, 32, 32)
    assert torch.equal(a[2]["maps"], b[2]["maps"])  # every model sees the same images
    train = ProceduralMaterials(3, 32, seed=0)
    assert not torch.equal(a[0]["maps"], train[0]["maps"])
    assert str(TEST_SEED) in a.description


def test_shards_are_centre_cropped_to_the_model_resolution(tmp_path):
    from svbrdf_train.data.shards import ShardWriter

    data = ProceduralMaterials(2, 48, seed=3)
    with ShardWriter(tmp_path / "t.h5", 48, bits=16) as w:
        w.extend(data.batch([0, 1]))
    test = make_test_set(tmp_path / "t.h5", 32, 99)
    assert len(test) == 2  # the shard's samples, not the procedural count
    stored = test.data[1]
    assert torch.equal(test[1]["maps"], stored["maps"][:, 8:40, 8:40])
    with pytest.raises(BenchError, match="smaller than the 64 px"):
        make_test_set(tmp_path / "t.h5", 64, 1)[0]


@pytest.mark.data
def test_des18_folder(shared_data):
    test = make_test_set(shared_data / "des18-dev", 256, 5)
    assert len(test) > 5 and test[0]["maps"].shape == (10, 256, 256)
    assert "Des18" in test.description


def test_missing_and_wrong_paths_are_refused(tmp_path):
    with pytest.raises(BenchError, match="no such file"):
        make_test_set(tmp_path / "nowhere", 32, 1)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(BenchError, match="not a Des18 folder"):
        make_test_set(tmp_path / "notes.txt", 32, 1)
