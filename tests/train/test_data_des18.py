"""Des18 folders: round trip through svbrdf-render's writer, crops, the eight transforms, layouts, errors."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, MapFileError, Scene, read_des18, render, write_des18
from svbrdf_train.data.real.des18 import Des18Folder, dihedral, dihedral_image

STEP8 = 1 / 255


def _strips(folder, count=3, size=48, *, bits=8, rendered=False, seed=0):
    """Write ``count`` strips of random maps; the photo is noise, or the maps rendered under an
    on-axis flash (scaled to stay below 1, so nothing clips)."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for i in range(count):
        maps = random_svbrdf(1, size, seed=seed + i, roughness=(0.3, 0.9))
        if rendered:
            scene = _flash(maps)
            photo = render(maps, scene)
        else:
            photo = torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(100 + i))
        name = f"{i:07d};MatAXMatB;0X1.png"
        write_des18(folder / name, photo, maps, bits=bits)
        written.append((name, photo, maps))
    return written


def _flash(maps: SVBRDF) -> Scene:
    peak = float(render(maps, Scene.flash(intensity=1.0)).max())
    return Scene.flash(intensity=0.9 / peak)


def _max_diff(a, b) -> float:
    return float((a - b).abs().max())


# -- test split: what was written comes back --------------------------------------------------


def test_round_trip_centre_crop(tmp_path):
    written = _strips(tmp_path, count=3, size=48)
    data = Des18Folder(tmp_path, split="test", crop=32)
    assert len(data) == 3
    assert not data.augment and not data.random_crop
    for i, (name, photo, maps) in enumerate(written):
        sample = data[i]
        assert sample["name"] == name
        assert sample["input"].shape == (3, 32, 32) and sample["input"].dtype == torch.float32
        assert sample["maps"].shape == (10, 32, 32) and sample["maps"].dtype == torch.float32
        want = maps.center_crop(32)
        got = SVBRDF.unpack(sample["maps"][None])
        assert _max_diff(sample["input"], photo[0, :, 8:40, 8:40]) <= STEP8 / 2 + 1e-6
        for map_name in ("diffuse", "roughness", "specular"):
            assert _max_diff(getattr(got, map_name), getattr(want, map_name)) <= STEP8 / 2 + 1e-6
        # (n + 1) / 2 at 8 bits, decoded by 2x - 1 and re-normalised: about two steps.
        assert _max_diff(got.normal, want.normal) <= 2 * STEP8
        assert torch.allclose(got.normal.norm(dim=1), torch.ones(1), atol=1e-5)


def test_whole_tiles_and_default_collate(tmp_path):
    _strips(tmp_path, count=2, size=40)
    data = Des18Folder(tmp_path, split="test", crop=None)
    batch = torch.utils.data.default_collate([data[0], data[1]])
    assert batch["input"].shape == (2, 3, 40, 40) and batch["maps"].shape == (2, 10, 40, 40)
    assert len(batch["name"]) == 2


# -- train split: random windows and the eight transforms ---------------------------------------


@pytest.mark.parametrize("k", range(8))
def test_transforms_commute_with_an_on_axis_flash(k):
    """Rendering the transformed maps = transforming the rendering: normals turn with the pixels."""
    maps = random_svbrdf(1, 24, seed=k, roughness=(0.3, 0.9))
    scene = _flash(maps)
    expected = dihedral_image(render(maps, scene), k)
    assert _max_diff(render(dihedral(maps, k), scene), expected) < 1e-5
    if k != 0:  # moving the pixels without turning the normals fails the same check
        others = (dihedral_image(m, k) for m in (maps.diffuse, maps.roughness, maps.specular))
        pixels_only = SVBRDF(dihedral_image(maps.normal, k), *others)
        assert _max_diff(render(pixels_only, scene), expected) > 0.05


def test_augmented_photo_is_the_photo_of_the_augmented_maps(tmp_path):
    """Strips whose photo is a rendering: after augmentation the photo still matches the maps."""
    written = _strips(tmp_path, count=3, size=32, bits=16, rendered=True)
    scenes = [_flash(maps) for _, _, maps in written]
    seen = set()
    for seed in range(4):
        data = Des18Folder(tmp_path, split="train", crop=None, seed=seed)
        for i in range(len(data)):
            sample = data[i]
            seen.add(data.placement(i, 32).dihedral)
            maps = SVBRDF.unpack(sample["maps"][None])
            assert _max_diff(render(maps, scenes[i])[0], sample["input"]) < 1e-3
    assert len(seen) >= 4  # the check ran on several transforms, not only the identity


def test_random_window_cuts_photo_and_maps_alike(tmp_path):
    _strips(tmp_path, count=2, size=40, bits=16, rendered=True)
    data = Des18Folder(tmp_path, split="train", crop=24, seed=3)
    for i in range(len(data)):
        top, left, k = data.placement(i, 40)
        strip = read_des18(data.files[i])
        sample = data[i]
        assert sample["input"].shape == (3, 24, 24)
        assert torch.equal(sample["maps"], dihedral(strip.svbrdf, k).crop(top, left, 24).pack()[0])
        full_photo = dihedral_image(strip.input, k)[0]
        assert torch.equal(sample["input"], full_photo[:, top : top + 24, left : left + 24])


def test_draws_repeat_per_seed_and_epoch_and_change_with_them(tmp_path):
    _strips(tmp_path, count=3, size=48)
    a = Des18Folder(tmp_path, split="train", crop=16, seed=5)
    b = Des18Folder(tmp_path, split="train", crop=16, seed=5)
    first = [a.placement(i, 48) for i in range(3)]
    assert first == [b.placement(i, 48) for i in range(3)]
    assert torch.equal(a[1]["maps"], b[1]["maps"]) and torch.equal(a[1]["input"], b[1]["input"])
    a.set_epoch(1)
    assert [a.placement(i, 48) for i in range(3)] != first
    a.set_epoch(0)
    assert [a.placement(i, 48) for i in range(3)] == first
    other_seed = Des18Folder(tmp_path, split="train", crop=16, seed=6)
    assert [other_seed.placement(i, 48) for i in range(3)] != first


def test_augment_and_random_crop_switches(tmp_path):
    _strips(tmp_path, count=1, size=48)
    centred = Des18Folder(tmp_path, split="train", crop=16, random_crop=False, augment=False, seed=1)
    assert centred.placement(0, 48) == (16, 16, 0)
    mirrored_only = Des18Folder(tmp_path, split="train", crop=16, random_crop=False, seed=1)
    assert mirrored_only.placement(0, 48)[:2] == (16, 16)
    window_only = Des18Folder(tmp_path, split="train", crop=16, augment=False, seed=1)
    assert window_only.placement(0, 48).dihedral == 0
    # The window does not depend on whether the transform is drawn.
    assert window_only.placement(0, 48)[:2] == Des18Folder(tmp_path, crop=16, seed=1).placement(0, 48)[:2]


# -- layouts and errors -----------------------------------------------------------------------


def test_published_layout_picks_the_split_folder(tmp_path):
    _strips(tmp_path / "trainBlended", count=2, size=16)
    _strips(tmp_path / "testBlended", count=1, size=16, seed=7)
    assert len(Des18Folder(tmp_path, split="train", crop=8)) == 2
    assert len(Des18Folder(tmp_path, split="test", crop=8)) == 1
    assert len(Des18Folder(tmp_path / "testBlended", split="test", crop=8)) == 1
    assert len(Des18Folder(tmp_path / "testBlended", split="train", crop=8)) == 1  # the folder given


def test_missing_split_folder_says_which_exists(tmp_path):
    _strips(tmp_path / "trainBlended", count=1, size=16)
    with pytest.raises(DataError, match="trainBlended/ but no testBlended/"):
        Des18Folder(tmp_path, split="test")


def test_empty_folder_names_it_and_the_layout(tmp_path):
    (tmp_path / "notes.txt").write_text("no strips here")
    (tmp_path / "._0000001;A;B.png").write_bytes(b"macOS resource fork")  # hidden: ignored
    with pytest.raises(DataError, match="no Des18 strips") as err:
        Des18Folder(tmp_path)
    assert str(tmp_path) in str(err.value) and "trainBlended" in str(err.value)
    with pytest.raises(DataError, match="does not exist"):
        Des18Folder(tmp_path / "nowhere")


def test_crop_larger_than_the_tile_names_the_file(tmp_path):
    _strips(tmp_path, count=1, size=16)
    data = Des18Folder(tmp_path, split="test", crop=32)
    with pytest.raises(DataError, match=r"0000000;MatAXMatB;0X1\.png: tiles are 16x16.*crop of 32"):
        data[0]


def test_bad_file_raises_the_readers_error_naming_it(tmp_path):
    _strips(tmp_path, count=1, size=16)
    (tmp_path / "0000009;broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    data = Des18Folder(tmp_path, split="test", crop=8)
    assert len(data) == 2
    with pytest.raises(MapFileError, match=r"0000009;broken\.png"):
        data[1]


@pytest.mark.parametrize(
    "kwargs, match",
    [({"split": "val"}, "split"), ({"crop": 0}, "crop"), ({"crop": 2.5}, "crop"), ({"seed": -1}, "seed")],
)
def test_bad_arguments(tmp_path, kwargs, match):
    _strips(tmp_path, count=1, size=16)
    with pytest.raises(DataError, match=match):
        Des18Folder(tmp_path, **kwargs)


def test_index_out_of_range(tmp_path):
    _strips(tmp_path, count=2, size=16)
    data = Des18Folder(tmp_path, split="test", crop=8)
    assert data[-1]["name"] == data[1]["name"]
    with pytest.raises(IndexError):
        data[2]


# -- the reference data -----------------------------------------------------------------------


@pytest.mark.data
def test_des18_dev_centre_crops(shared_data):
    data = Des18Folder(shared_data / "des18-dev", split="test", crop=256)
    assert len(data) == 21
    for i in range(len(data)):
        sample = data[i]
        assert sample["name"] == data.files[i].name and sample["name"].endswith(".png")
        x, maps = sample["input"], sample["maps"]
        assert x.shape == (3, 256, 256) and maps.shape == (10, 256, 256)
        assert float(x.min()) >= 0 and float(x.max()) <= 1
        assert float(maps[3:].min()) >= 0 and float(maps[3:].max()) <= 1
        assert torch.allclose(maps[:3].norm(dim=0), torch.ones(256, 256), atol=1e-5)
        assert float(maps[2].min()) > 0  # normals face the camera
