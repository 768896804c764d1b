"""Map files: Des18 strips and map folders, round trips and bad files."""

from __future__ import annotations

import numpy as np
import png
import pytest
import torch
from PIL import Image

from conftest import random_svbrdf
from svbrdf_render import (
    MapFileError,
    read_des18,
    read_image,
    read_map_folder,
    write_des18,
    write_image,
    write_map_folder,
)


def _close_maps(a, b, atol):
    for name in ("normal", "diffuse", "roughness", "specular"):
        diff = (getattr(a, name) - getattr(b, name)).abs().max()
        assert float(diff) <= atol, f"{name}: max difference {float(diff)} > {atol}"


@pytest.mark.parametrize("bits, atol", [(8, 0.5 / 255 * 2 + 1e-6), (16, 0.5 / 65535 * 2 + 1e-6)])
def test_des18_round_trip(tmp_path, bits, atol):
    m = random_svbrdf(1, 16, seed=1)
    photo = torch.rand(1, 3, 16, 16)
    path = write_des18(tmp_path / "s.png", photo, m, bits=bits)
    with Image.open(path) as im:
        assert im.size == (80, 16)
    sample = read_des18(path)
    assert sample.input.shape == (1, 3, 16, 16)
    assert float((sample.input - photo).abs().max()) <= atol
    # Normals are stored as (n+1)/2 and re-normalised on reading: quantisation error is
    # doubled by the 2x-1 decode, then spread by the normalisation.
    _close_maps(sample.svbrdf, m, atol * 2)


@pytest.mark.parametrize("bits", [8, 16])
def test_map_folder_round_trip(tmp_path, bits):
    m = random_svbrdf(1, 8, seed=2)
    paths = write_map_folder(tmp_path / "maps", m, bits=bits)
    assert sorted(p.name for p in paths.values()) == [
        "diffuse.png", "normal.png", "roughness.png", "specular.png",
    ]
    with Image.open(paths["roughness"]) as im:  # one grey channel
        assert im.mode in ("L", "I", "I;16", "I;16B")
    back = read_map_folder(tmp_path / "maps")
    _close_maps(back, m, 2.0 / (2**bits - 1) + 1e-6)


def test_srgb_albedo_option_decodes(tmp_path):
    m = random_svbrdf(1, 4)
    write_map_folder(tmp_path, m)
    lin = read_map_folder(tmp_path)
    srgb = read_map_folder(tmp_path, albedo_encoding="srgb")
    assert torch.all(srgb.diffuse <= lin.diffuse + 1e-6)  # decoding darkens mid-tones
    assert torch.equal(srgb.roughness, lin.roughness)


def test_reads_the_shared_des18_samples(shared_data):
    files = sorted((shared_data / "des18-dev").glob("*.png"))
    assert files
    s = read_des18(files[0])
    assert s.input.shape == (1, 3, 288, 288)
    assert torch.allclose(s.svbrdf.normal.norm(dim=1), torch.ones(1, 288, 288), atol=1e-5)
    assert float(s.svbrdf.normal[:, 2].min()) > 0  # tangent-space normals point out


# -- bad files ----------------------------------------------------------------------------


def _save(path, arr):
    Image.fromarray(arr).save(path)
    return path


def test_truncated_png_is_a_clear_error(tmp_path):
    p = write_des18(tmp_path / "s.png", torch.rand(3, 16, 16), random_svbrdf(1, 16))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError) as e:
        read_des18(p)
    assert str(p) in str(e.value)


def test_truncated_16bit_png_is_a_clear_error(tmp_path):
    p = write_image(tmp_path / "a.png", torch.rand(3, 32, 32), bits=16)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError, match="16-bit PNG"):
        read_image(p)


def test_not_an_image_and_missing_file(tmp_path):
    p = tmp_path / "notes.png"
    p.write_text("hello")
    with pytest.raises(MapFileError, match="cannot decode"):
        read_image(p)
    with pytest.raises(MapFileError, match="no such file"):
        read_image(tmp_path / "absent.png")


def test_wrong_tile_count_and_non_square_tiles(tmp_path):
    four = _save(tmp_path / "four.png", np.zeros((16, 64, 3), np.uint8))
    with pytest.raises(MapFileError, match="has 4 square tiles"):
        read_des18(four)
    wide = _save(tmp_path / "wide.png", np.zeros((16, 90, 3), np.uint8))
    with pytest.raises(MapFileError, match="not five square tiles"):
        read_des18(wide)


def test_grey_strip_is_refused_but_grey_roughness_is_read(tmp_path):
    grey = _save(tmp_path / "g.png", np.zeros((16, 80), np.uint8))
    with pytest.raises(MapFileError, match="grey"):
        read_des18(grey)
    write_map_folder(tmp_path / "m", random_svbrdf(1, 8))
    rough = read_map_folder(tmp_path / "m").roughness
    assert rough.shape == (1, 1, 8, 8)
    _save(tmp_path / "m" / "normal.png", np.full((8, 8), 128, np.uint8))
    with pytest.raises(MapFileError, match="normal map needs 3 channels"):
        read_map_folder(tmp_path / "m")


def test_grey_diffuse_is_replicated(tmp_path):
    write_map_folder(tmp_path, random_svbrdf(1, 8))
    _save(tmp_path / "diffuse.png", np.full((8, 8), 51, np.uint8))
    d = read_map_folder(tmp_path).diffuse
    assert d.shape == (1, 3, 8, 8) and torch.allclose(d, torch.full_like(d, 0.2))


def test_rgba_opaque_is_accepted_translucent_refused(tmp_path):
    rgb = (np.random.default_rng(0).random((16, 80, 3)) * 255).astype(np.uint8)
    opaque = np.concatenate([rgb, np.full((16, 80, 1), 255, np.uint8)], axis=2)
    p = _save(tmp_path / "opaque.png", opaque)
    assert torch.allclose(read_des18(p).input, torch.from_numpy(rgb[:, :16]).permute(2, 0, 1)[None] / 255.0)
    opaque[0, 0, 3] = 10
    p = _save(tmp_path / "translucent.png", opaque)
    with pytest.raises(MapFileError, match="translucent alpha"):
        read_des18(p)


def test_sixteen_bit_strip_keeps_its_precision(tmp_path):
    arr = (np.random.default_rng(1).random((16, 80, 3)) * 65535).astype(np.uint16)
    p = tmp_path / "s16.png"
    png.from_array(arr.reshape(16, -1), "RGB;16").save(str(p))
    s = read_des18(p)
    expected = torch.from_numpy(arr[:, :16].astype(np.float32) / 65535).permute(2, 0, 1)[None]
    assert torch.allclose(s.input, expected, atol=1e-7)


def test_palette_png_is_expanded(tmp_path):
    im = Image.fromarray((np.random.default_rng(2).random((8, 8, 3)) * 255).astype(np.uint8))
    im.convert("P").save(tmp_path / "p.png")
    assert read_image(tmp_path / "p.png").shape == (3, 8, 8)


def test_folder_errors_list_missing_maps_and_size_mismatch(tmp_path):
    write_map_folder(tmp_path, random_svbrdf(1, 8))
    (tmp_path / "specular.png").unlink()
    with pytest.raises(MapFileError) as e:
        read_map_folder(tmp_path)
    assert "missing map(s) specular" in str(e.value) and "normal.png" in str(e.value)
    _save(tmp_path / "specular.png", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(MapFileError, match="same size"):
        read_map_folder(tmp_path)
    with pytest.raises(MapFileError, match="not a folder"):
        read_map_folder(tmp_path / "nope")


def test_write_image_is_atomic_and_clamps(tmp_path):
    p = write_image(tmp_path / "sub" / "x.png", torch.tensor([[[-1.0, 0.5, 2.0]]]).expand(3, 1, 3))
    with Image.open(p) as im:
        arr = np.asarray(im)
    assert arr[0, :, 0].tolist() == [0, 128, 255]
    assert [q.name for q in p.parent.iterdir()] == ["x.png"]  # no temporary left behind


# -- encodings inside the file and OpenEXR ---------------------------------------------------------


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("encoding", ["srgb", "linear"])
def test_png_says_its_encoding_and_keeps_its_values(tmp_path, bits, encoding):
    from svbrdf_render import read_png_encoding

    x = torch.rand(3, 6, 5)
    plain = write_image(tmp_path / "plain.png", x, bits=bits)
    tagged = write_image(tmp_path / "tagged.png", x, bits=bits, encoding=encoding, note="a test")
    assert read_png_encoding(plain) is None
    assert read_png_encoding(tagged) == encoding
    assert torch.equal(read_image(tagged), read_image(plain))  # the tag changes no value
    with Image.open(tagged) as im:  # still a valid PNG for Pillow, with the gamma it declares
        im.load()
        assert im.info["gamma"] == pytest.approx(1 / 2.2 if encoding == "srgb" else 1.0, abs=1e-4)
        assert im.info["Comment"] == "a test"
    if bits == 16:  # pypng checks every chunk's CRC
        with open(tagged, "rb") as f:
            chunks = [kind for kind, _ in png.Reader(file=f).chunks()]
        assert chunks[0] == b"IHDR" and chunks.index(b"cICP") < chunks.index(b"IDAT")


def test_grey_png_tag_and_bad_encoding(tmp_path):
    from svbrdf_render import read_png_encoding

    path = write_image(tmp_path / "r.png", torch.rand(1, 4, 4), encoding="linear")
    assert read_png_encoding(path) == "linear"
    assert read_image(path, channels=1).shape == (1, 4, 4)
    with pytest.raises(ValueError, match="encoding"):
        write_image(tmp_path / "x.png", torch.rand(3, 4, 4), encoding="rec2020")
    assert not (tmp_path / "x.png").exists()


def test_map_folder_auto_reads_the_albedo_tag(tmp_path):
    from svbrdf_render import linear_to_srgb

    m = random_svbrdf(1, 8, seed=3)
    write_map_folder(tmp_path, m)
    write_image(tmp_path / "diffuse.png", linear_to_srgb(m.diffuse[0]), encoding="srgb")
    back = read_map_folder(tmp_path)  # auto: diffuse decoded from sRGB, specular (untagged) as stored
    assert float((back.diffuse - m.diffuse).abs().max()) < 0.02
    assert float((back.specular - m.specular).abs().max()) <= 1 / 255 + 1e-6
    as_stored = read_map_folder(tmp_path, albedo_encoding="linear")
    assert float((as_stored.diffuse - m.diffuse).abs().max()) > 0.05


def test_exr_round_trip(tmp_path):
    exr = pytest.importorskip("OpenEXR")
    from svbrdf_render import write_exr

    x = torch.rand(3, 5, 7) * 4  # linear values above 1 are kept
    path = write_exr(tmp_path / "x.exr", x)
    pixels = exr.File(str(path)).channels()["RGB"].pixels
    assert pixels.shape == (5, 7, 3) and pixels.dtype == np.float16
    assert np.allclose(pixels.astype(np.float32), x.permute(1, 2, 0).numpy(), rtol=1e-3)
    grey = write_exr(tmp_path / "g.exr", torch.rand(1, 4, 4), half=False)
    assert exr.File(str(grey)).channels()["Y"].pixels.dtype == np.float32
