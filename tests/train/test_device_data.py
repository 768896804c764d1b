"""Training batches made on the training device (``data.generate: device``): ``fitdata.device_batch``
gives what a DataLoader gives, procedural data computed on the device reproduces and follows the
CPU's distribution, and the recipe field takes only its two values.

The CUDA variants run where ``torch.cuda.is_available()`` and skip elsewhere."""

from __future__ import annotations

import pytest
import torch
from test_data_shards import _shard
from torch.utils.data import ConcatDataset, DataLoader, Subset

from conftest import des18_strips
from svbrdf_models.errors import DataError
from svbrdf_train.data.fitdata import Mixture, build_datasets, device_batch
from svbrdf_train.data.procedural import FAMILIES, ProceduralMaterials, materials
from svbrdf_train.data.simulated_photo import PhotoSettings, _photos
from svbrdf_train.recipe import load_recipe

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
DEVICES = ["cpu", pytest.param("cuda", marks=CUDA)]


def _loader_batch(dataset, indices):
    """What a DataLoader (default collate, no workers) gives for ``indices`` as one batch."""
    return next(iter(DataLoader(dataset, batch_size=len(indices), sampler=indices)))


def _assert_same(got: dict, want: dict) -> None:
    assert list(got) == list(want)
    for key, value in want.items():
        if isinstance(value, torch.Tensor):
            assert got[key].device == value.device and got[key].dtype == value.dtype, key
            assert torch.equal(got[key], value), key
        else:
            assert got[key] == value, key


def _epochs(mix: Mixture) -> list:
    return [getattr(getattr(s, "dataset", s), "epoch", None) for s in mix.sources]


# -- device_batch gives what a DataLoader gives ------------------------------------------------


def test_procedural_training_and_validation_sets():
    train, val = build_datasets(load_recipe("ours", "smoke", {"data.count": 64}))
    assert isinstance(train, ProceduralMaterials)
    indices = [5, 0, 63, 7, 7]  # any order, repeats
    _assert_same(device_batch(train, indices, "cpu"), _loader_batch(train, indices))
    _assert_same(device_batch(val, [1, 0], torch.device("cpu")), _loader_batch(val, [1, 0]))


def test_subsets_map_their_indices(tmp_path):
    data = ProceduralMaterials(40, 24, seed=3, mix=0.5)
    nested = Subset(Subset(data, range(10, 40)), [29, 0, 5, 5, 17])
    _assert_same(device_batch(nested, [4, 0, 2], "cpu"), _loader_batch(nested, [4, 0, 2]))
    # The shards source builds Subsets of a ShardDataset (training part and held-out part).
    _shard(tmp_path / "a.h5", count=10, size=32)
    recipe = load_recipe("ours", "smoke", {"data.source": "shards", "data.path": str(tmp_path / "a.h5")})
    train, val = build_datasets(recipe)
    assert isinstance(train, Subset)
    _assert_same(device_batch(train, [7, 1, 3], "cpu"), _loader_batch(train, [7, 1, 3]))
    _assert_same(device_batch(val, [1, 0], "cpu"), _loader_batch(val, [1, 0]))


def test_a_mix_of_procedural_data_and_shards(tmp_path):
    _shard(tmp_path / "real.h5", count=12, size=32)
    mix = [
        {"source": "procedural", "weight": 1.0},
        {"source": "shards", "weight": 1.0, "path": str(tmp_path / "real.h5"), "validation": 2},
    ]
    train, val = build_datasets(load_recipe("ours-mix", "smoke", {"data.count": 40, "data.mix": mix}))
    assert isinstance(train, Mixture) and isinstance(val, ConcatDataset)
    train.set_epoch(2)
    indices = list(range(0, 40, 3))
    assert set(train.which[indices].tolist()) == {0, 1}  # both sources in the batch
    _assert_same(device_batch(train, indices, "cpu"), _loader_batch(train, indices))
    # The validation set: both sources' held-out parts, put together.
    _assert_same(device_batch(val, [3, 0, 2, 1], "cpu"), _loader_batch(val, [3, 0, 2, 1]))


def test_a_mix_with_real_strips_reads_each_pass_under_its_epoch(tmp_path):
    real = des18_strips(tmp_path / "real", count=3, size=64)
    recipe = load_recipe("ours-mix", "smoke", {"data.path": str(real), "data.count": 24, "data.validation": 1})
    train, _ = build_datasets(recipe)
    train.set_epoch(1)
    indices = list(range(24))
    assert int(train.passes.max()) > 1  # two strips met many times: several crops each
    want = _loader_batch(train, indices)
    want_epochs = _epochs(train)
    train.sources[1].dataset.set_epoch(12345)  # device_batch sets every epoch it reads under
    got = device_batch(train, indices, "cpu")
    _assert_same(got, want)
    assert _epochs(train) == want_epochs  # and leaves them as the DataLoader's loop did


def test_refuses_an_empty_batch():
    with pytest.raises(DataError, match="at least one sample index"):
        device_batch(ProceduralMaterials(4, 16), [], "cpu")


# -- procedural data on a device ---------------------------------------------------------------


@pytest.mark.parametrize("device", DEVICES)
def test_the_same_seed_and_indices_give_the_same_bytes(device):
    data = ProceduralMaterials(100, 32, seed=11, mix=0.5, photo=PhotoSettings(gamma_probability=0.3))
    a = device_batch(data, [3, 97, 40, 41], device)
    b = device_batch(ProceduralMaterials(100, 32, seed=11, mix=0.5, photo=data.photo), [3, 97, 40, 41], device)
    assert a["input"].device.type == a["maps"].device.type == torch.device(device).type
    assert torch.equal(a["input"], b["input"]) and torch.equal(a["maps"], b["maps"])
    assert a["name"] == b["name"] == [f"procedural:11:{i}" for i in (3, 97, 40, 41)]


@pytest.mark.parametrize("device", DEVICES)
def test_a_batch_on_a_device_is_its_samples_one_by_one(device):
    data = ProceduralMaterials(50, 24, seed=2, mix=0.5)
    batch = data.batch([4, 9, 1], device=device)
    for k, i in enumerate([4, 9, 1]):
        item = data.batch([i], device=device)
        assert torch.equal(batch["maps"][k], item["maps"][0]) and torch.equal(batch["input"][k], item["input"][0])


def test_the_batched_photo_render_gives_the_per_sample_bytes_on_the_cpu():
    """The one render of a whole batch that accelerators use, checked where it can be: on the
    CPU it makes the bytes of one render per sample (camera, flash, exposure, noise, clip and
    gamma per sample; any size, so odd ones too)."""
    for resolution in (32, 37):
        data = ProceduralMaterials(60, resolution, seed=4, mix=0.5, photo=PhotoSettings(gamma_probability=0.5))
        indices = list(range(10, 16))
        batch = data.batch(indices)
        photos = _photos(batch["maps"], [data.scene(i) for i in indices])
        assert torch.equal(photos, batch["input"])


def test_the_fields_stay_on_the_device_they_are_asked_for():
    """Computed on the meta device, which refuses (most) ops that mix in a CPU tensor: every
    table and grid of the generator is placed on the device, not only the result."""
    # 12 mixtures: the first that hold all ten families of generator 3.
    maps, names = materials(0, range(12), 8, mix=1.0, device="meta")  # ~3 s: meta ops run in Python
    assert {f for n in names for f in n.split("+")} == set(FAMILIES)  # every family, and the masks
    assert {t.device.type for t in maps.maps().values()} == {"meta"}


def _stats(batch: dict) -> torch.Tensor:
    """Per-channel means and standard deviations of the maps, and the photos' mean."""
    maps, photo = batch["maps"].double(), batch["input"].double()
    return torch.cat([maps.mean(dim=(0, 2, 3)), maps.std(dim=(0, 2, 3)), photo.mean().view(1)]).cpu()


@pytest.mark.parametrize("device", DEVICES)
def test_the_device_draws_the_cpu_distribution(device):
    """64 samples at 32 px made on the CPU (a DataLoader, as workers make them) and on the device.

    Tolerance 5e-3 (absolute; maps and photos lie in [-1, 1]): the draws are made on the CPU
    in both cases, so every sample is the same material under the same camera, flash and
    exposure; maps differ only in float rounding (~1e-7) and in the few pixels where rounding
    moves a floor() or comparison across a tile, cell or thread edge, and photos in their
    noise, another draw of std at most ~0.1 per value, whose effect on a mean over 64 x 3 x
    32 x 32 values is ~0.1 / sqrt(196608) ~ 2e-4. 5e-3 is 20 times that, and far below what a
    change of the distribution moves (a family's weight, a palette: 1e-2 and more). On the
    CPU the two are the same bytes.
    """
    data = ProceduralMaterials(1000, 32, seed=21)
    indices = list(range(500, 564))
    cpu = _stats(_loader_batch(data, indices))
    on_device = _stats(device_batch(data, indices, device))
    assert torch.allclose(on_device, cpu, rtol=0, atol=5e-3), (on_device - cpu).abs().max()
    if device == "cpu":
        assert torch.equal(on_device, cpu)


@CUDA
def test_cuda_maps_are_the_cpu_maps_up_to_rounding():
    data = ProceduralMaterials(100, 32, seed=8, mix=0.5)
    indices = list(range(16))
    cpu = data.batch(indices)["maps"]
    gpu = data.batch(indices, device="cuda")["maps"].cpu()
    close = (gpu - cpu).abs() < 1e-4
    assert close.float().mean() > 0.99  # the rest: edges a rounding moved by a pixel


# -- the recipe field ----------------------------------------------------------------------------


def test_the_recipe_field_defaults_to_workers_and_takes_device():
    assert load_recipe("ours", "smoke").data.generate == "workers"
    assert load_recipe("ours", "smoke", {"data.generate": "device"}).data.generate == "device"
