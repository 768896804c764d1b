"""Photo folders: the encoding is required and decoded as told, square crops, resizing, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image, ImageOps

from svbrdf_models.errors import DataError
from svbrdf_render import MapFileError, write_image
from svbrdf_render.formats.mapfiles import srgb_to_linear
from svbrdf_train.data.photos import PhotoFolder


def _photo(seed: int, h: int = 24, w: int = 24) -> torch.Tensor:
    """Values on the 8-bit grid, so what is written is exactly what is read."""
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (3, h, w), generator=g).float() / 255


@pytest.fixture
def folder(tmp_path):
    write_image(tmp_path / "a.png", _photo(0))
    write_image(tmp_path / "b.png", _photo(1, 24, 40))  # landscape
    write_image(tmp_path / "c.PNG", _photo(2, 40, 24))  # portrait, upper-case extension
    (tmp_path / "notes.txt").write_text("not a photo")
    return tmp_path


def test_encoding_is_required(folder):
    with pytest.raises(TypeError, match="encoding"):
        PhotoFolder(folder)
    with pytest.raises(DataError, match="'srgb'.*'linear'"):
        PhotoFolder(folder, encoding="gamma")


def test_linear_is_as_stored_and_srgb_is_decoded(folder):
    linear = PhotoFolder(folder, encoding="linear")
    srgb = PhotoFolder(folder, encoding="srgb")
    assert [p.name for p in linear.files] == ["a.png", "b.png", "c.PNG"]
    stored = _photo(0)
    a_lin, a_srgb = linear[0], srgb[0]
    assert set(a_lin) == {"input", "name"} and a_lin["name"] == "a.png"
    assert torch.equal(a_lin["input"], stored)
    assert torch.allclose(a_srgb["input"], srgb_to_linear(stored), atol=1e-6)
    # sRGB-encoded values are brighter than the radiance they stand for (except at 0 and 1).
    mid = (stored > 0.05) & (stored < 0.95)
    assert bool((a_srgb["input"][mid] < stored[mid]).all())


def test_non_square_photos_are_centre_cropped(folder):
    data = PhotoFolder(folder, encoding="linear")
    landscape, portrait = data[1]["input"], data[2]["input"]
    assert landscape.shape == portrait.shape == (3, 24, 24)
    assert torch.equal(landscape, _photo(1, 24, 40)[:, :, 8:32])
    assert torch.equal(portrait, _photo(2, 40, 24)[:, 8:32, :])


def test_size_resamples_every_photo_to_one_batchable_size(folder):
    data = PhotoFolder(folder, encoding="srgb", size=16)
    batch = torch.utils.data.default_collate([data[i] for i in range(len(data))])
    assert batch["input"].shape == (3, 3, 16, 16)
    assert float(batch["input"].min()) >= 0 and float(batch["input"].max()) <= 1
    # Averaging happens on linear values: a uniform photo stays uniform and keeps its value.
    write_image(folder / "flat.png", torch.full((3, 30, 30), 128 / 255))
    flat = PhotoFolder(folder, encoding="linear", size=16, pattern="flat*")
    assert torch.allclose(flat[0]["input"], torch.full((3, 16, 16), 128 / 255), atol=1e-6)


def test_pattern_selects_files(folder):
    data = PhotoFolder(folder, encoding="linear", pattern="[ab]*")
    assert [p.name for p in data.files] == ["a.png", "b.png"]


def test_jpeg_is_read(tmp_path):
    ramp = torch.linspace(0.1, 0.9, 24)
    stored = torch.stack([ramp.expand(24, 24), ramp[:, None].expand(24, 24), torch.full((24, 24), 0.5)])
    arr = (stored.permute(1, 2, 0).numpy() * 255).round().astype("uint8")
    Image.fromarray(arr).save(tmp_path / "phone.jpg", quality=95, subsampling=0)
    sample = PhotoFolder(tmp_path, encoding="srgb")[0]
    assert sample["name"] == "phone.jpg" and sample["input"].shape == (3, 24, 24)
    assert float((sample["input"] - srgb_to_linear(stored)).abs().max()) < 0.02


def test_empty_folder_and_pattern_without_match(tmp_path):
    (tmp_path / "readme.txt").write_text("nothing")
    with pytest.raises(DataError, match="no photos matching") as err:
        PhotoFolder(tmp_path, encoding="linear")
    assert str(tmp_path) in str(err.value)
    write_image(tmp_path / "a.png", _photo(0))
    with pytest.raises(DataError, match="'luo2024_\\*'"):
        PhotoFolder(tmp_path, encoding="linear", pattern="luo2024_*")
    with pytest.raises(DataError, match="does not exist"):
        PhotoFolder(tmp_path / "nowhere", encoding="linear")


def test_unreadable_photo_names_the_file(tmp_path):
    (tmp_path / "broken.jpg").write_bytes(b"\xff\xd8\xff not a jpeg")
    data = PhotoFolder(tmp_path, encoding="srgb")
    with pytest.raises(MapFileError, match=r"broken\.jpg"):
        data[0]


@pytest.mark.data
def test_real_dev_photos(shared_data):
    folder = shared_data / "real-dev"
    linear = PhotoFolder(folder, encoding="linear", pattern="deschaintre2018_*", size=256)
    phones = PhotoFolder(folder, encoding="srgb", pattern="luo2024_*", size=256)
    assert (len(linear), len(phones)) == (13, 8)
    for data in (linear, phones):
        for i in range(len(data)):
            x = data[i]["input"]
            assert x.shape == (3, 256, 256)
            assert float(x.min()) >= 0 and float(x.max()) <= 1 and float(x.mean()) > 0.005
    # Decoding sRGB darkens: the same files read as linear are brighter on average.
    as_stored = PhotoFolder(folder, encoding="linear", pattern="luo2024_*")
    assert float(as_stored[0]["input"].mean()) > float(phones[0]["input"].mean())


@pytest.mark.parametrize("orientation", range(1, 9))
def test_the_exif_orientation_is_applied_as_predict_does(tmp_path, orientation):
    """A 24x40 PNG with EXIF Orientation k reads as Pillow's exif_transpose shows it, then its centre
    square: what `svbrdf-bench run --real-data` predicts from, as `svbrdf-train predict` does."""
    stored = (_photo(5, 24, 40).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored).save(tmp_path / "shot.png", exif=exif)
    with Image.open(tmp_path / "shot.png") as im:
        assert im.getexif()[0x0112] == orientation  # the tag is in the file
        shown = torch.from_numpy(np.asarray(ImageOps.exif_transpose(im), dtype=np.float32) / 255)
    h, w = shown.shape[:2]
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    expected = shown.permute(2, 0, 1)[:, top : top + s, left : left + s]
    got = PhotoFolder(tmp_path, encoding="linear")[0]["input"]
    assert got.shape == expected.shape == (3, 24, 24)
    assert torch.equal(got, expected)
