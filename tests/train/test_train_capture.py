"""Capture (``svbrdf_models.capture.one`` through ``svbrdf-train predict``): from real photos to maps.

Photos are made here: known maps rendered under a flash, or known pixel arrays, saved as PNG
(exact) or JPEG (quality 95). The geometry (EXIF orientation, crops, tiles) is checked against
known answers; the network's quality does not matter, so the command runs on a smoke checkpoint.
"""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from click.testing import CliRunner
from PIL import Image, ImageOps

from conftest import random_svbrdf, run_cli
from svbrdf_models.capture import (
    MAX_PIXELS,
    MIN_SIDE,
    CaptureOptions,
    PhotoError,
    capture_one,
    flash_consistency,
    load_photo,
    relight_frames,
    square,
    tile_count,
    tile_predict,
    to_directx,
)
from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, Scene, read_image, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb, srgb_to_linear
from svbrdf_train.cli import cli

OUTPUTS = ("normal", "diffuse", "roughness", "specular", "input", "rerender", "basecolor", "metallic",
           "metallic_roughness")  # fmt: skip
#: The material folder's files that are not PNG images.
RECORDS = {"material.json", "material.gltf", "material.mtlx", "index.html"}


# -- photos made here ----------------------------------------------------------------------------


def _pattern(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A smooth, colourful, asymmetric uint8 (h, w, 3) image (JPEG keeps it within a few levels)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.02, 0.08, 3)
    r = 0.5 + 0.4 * np.sin(f[0] * x + 0.3 * f[1] * y)
    g = 0.2 + 0.7 * (y / h) ** 1.5
    b = 0.5 + 0.4 * np.cos(f[2] * (x + 2 * y))
    return (np.stack([r, g, b], -1) * 255).round().astype(np.uint8)


def _flash_photo(size: int = 96) -> tuple[SVBRDF, torch.Tensor]:
    """Known maps and their linear flash photo (Des18 convention, clipped as a camera does)."""
    maps = example_material("tiles", size)
    photo = render(maps, Scene.flash(intensity=12.0)).clamp(0, 1)
    return maps, photo


def _png_header_only(path, w: int, h: int):
    """A PNG whose header claims w x h pixels (no pixel data): what a huge photo looks like
    before decoding, written in microseconds."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    return path


def _save(path, array: np.ndarray, mode: str | None = None, **kwargs):
    image = Image.fromarray(array)
    if mode is not None:
        image = image.convert(mode)
    image.save(path, **kwargs)
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A smoke generator (32 px), not tracked."""
    out = tmp_path_factory.mktemp("capture-fit") / "smoke"
    result = run_cli("fit", "--recipe", "ours", "--size", "smoke", "--out", str(out), "-q", "--no-track")
    assert result.returncode == 0, result.stderr
    return out / "last.pt"


def _invoke(*args):
    """``svbrdf-train predict ARGS`` in-process (faster than a fresh process)."""
    result = CliRunner().invoke(cli, ["predict", *map(str, args)])
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


# -- reading: orientation, crops, encoding -------------------------------------------------------


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied(tmp_path, orientation):
    """A 96x72 JPEG with EXIF Orientation k loads as Pillow's exif_transpose shows it (then its centre
    square), with a note when k != 1."""
    path = tmp_path / "shot.jpg"
    exif = Image.Exif()
    exif[0x0112] = orientation
    _save(path, _pattern(72, 96), quality=95, exif=exif)
    photo, notes = load_photo(path, linear=True)
    with Image.open(path) as im:
        shown = np.asarray(ImageOps.exif_transpose(im), dtype=np.float32) / 255
    expected = square(torch.from_numpy(shown).permute(2, 0, 1), None)
    assert photo.shape == (3, 72, 72)
    assert float((photo - expected).abs().max()) < 1e-6
    assert any("EXIF orientation" in n for n in notes) == (orientation != 1)


def test_exif_rotation_matches_the_rotated_original(tmp_path):
    """Orientation 6 (camera held upright, sensor sideways): the photo is the original turned a
    quarter clockwise, within JPEG error."""
    original = _pattern(72, 96, seed=3)
    path = tmp_path / "upright.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6
    _save(path, original, quality=95, exif=exif)
    photo, _ = load_photo(path, linear=True, crop=(0, 12, 72))
    turned = (
        torch.from_numpy(np.rot90(original, -1).copy()).permute(2, 0, 1).float() / 255
    )  # 72 wide, 96 high
    assert turned.shape == (3, 96, 72)
    error = (photo - turned[:, 12:84, :]).abs()
    assert float(error.mean()) < 0.01 and float(error.max()) < 0.1


def test_centre_square_and_user_crop_are_exact_on_png(tmp_path):
    """No crop: the largest centred square; --crop X,Y,SIZE: columns X.., rows Y.. of the photo."""
    array = np.random.default_rng(1).integers(0, 256, (80, 120, 3), dtype=np.uint8)
    path = _save(tmp_path / "shot.png", array)
    stored = torch.from_numpy(array).permute(2, 0, 1).float() / 255
    photo, notes = load_photo(path, linear=True)
    assert torch.equal(photo, stored[:, 0:80, 20:100]) and notes == []
    photo, _ = load_photo(path, linear=True, crop=(50, 10, 64))
    assert torch.equal(photo, stored[:, 10:74, 50:114])
    with pytest.raises(PhotoError, match=r"crop 60,10,64 does not fit in the 120x80 photo") as e:
        load_photo(path, crop=(60, 10, 64))
    assert str(path) in str(e.value) and isinstance(e.value, DataError)
    with pytest.raises(PhotoError, match=f"smaller than {MIN_SIDE}"):
        load_photo(path, crop=(0, 0, MIN_SIDE - 1))


@pytest.mark.parametrize("bits", [8, 16])
def test_srgb_photo_decodes_to_linear(tmp_path, bits):
    """Known linear values written sRGB-encoded read back linear within the file's quantisation
    (the sRGB decoding curve's slope is at most 2.3); --linear keeps the stored values."""
    linear = torch.linspace(0, 1, 3 * 64 * 64).view(3, 64, 64) ** 2
    path = write_image(tmp_path / "shot.png", linear_to_srgb(linear), bits=bits)
    photo, notes = load_photo(path)
    step = 1 / (255 if bits == 8 else 65535)
    assert float((photo - linear).abs().max()) <= 2.3 * step / 2 + 1e-6
    stored, _ = load_photo(path, linear=True)
    assert float((stored - linear_to_srgb(linear)).abs().max()) <= step / 2 + 1e-6
    assert any("16-bit" in n for n in notes) == (bits == 16)


# -- bad input: each case its own message ----------------------------------------------------------


def _case(tmp_path, kind):
    rgb = _pattern(80, 80)
    if kind == "missing":
        return tmp_path / "gone.jpg"
    if kind == "folder":
        (tmp_path / "shots").mkdir()
        return tmp_path / "shots"
    if kind == "not an image":
        (tmp_path / "notes.png").write_text("not an image\n")
        return tmp_path / "notes.png"
    if kind == "truncated":
        full = _save(tmp_path / "full.jpg", rgb, quality=95).read_bytes()
        (tmp_path / "cut.jpg").write_bytes(full[: len(full) // 3])
        return tmp_path / "cut.jpg"
    if kind == "bmp":
        return _save(tmp_path / "shot.bmp", rgb)
    if kind == "tiny":
        return _save(tmp_path / "tiny.png", _pattern(MIN_SIDE - 14, 80))
    if kind == "huge":
        return _png_header_only(tmp_path / "huge.png", 10_000, MAX_PIXELS // 10_000 + 1)
    if kind == "grey":
        return _save(tmp_path / "grey.jpg", rgb, "L", quality=95)
    if kind == "grey 16-bit":
        grey = (rgb[..., 1].astype(np.uint16) * 257)[None].astype(np.float32) / 65535
        return write_image(tmp_path / "grey16.png", torch.from_numpy(grey), bits=16)
    if kind == "translucent":
        rgba = np.concatenate([rgb, np.full((80, 80, 1), 255, np.uint8)], -1)
        rgba[:10, :10, 3] = 128
        return _save(tmp_path / "cutout.png", rgba)
    if kind == "opaque alpha":
        rgba = np.concatenate([rgb, np.full((80, 80, 1), 255, np.uint8)], -1)
        return _save(tmp_path / "opaque.png", rgba)
    if kind == "16-bit":
        return write_image(tmp_path / "deep.png", torch.from_numpy(rgb).permute(2, 0, 1) / 255, bits=16)
    if kind == "palette":
        image = Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE)
        image.save(tmp_path / "palette.png")
        return tmp_path / "palette.png"
    if kind == "cmyk":
        return _save(tmp_path / "print.jpg", rgb, "CMYK", quality=95)
    if kind == "grey as rgb":
        return _save(tmp_path / "greyish.png", np.repeat(rgb[..., 1:2], 3, -1))
    if kind == "overexposed":
        bright = rgb.copy()
        bright[20:40, 20:60] = 255
        return _save(tmp_path / "bright.png", bright)
    if kind == "small square":
        return _save(tmp_path / "small.png", _pattern(MIN_SIDE, 90))
    raise AssertionError(kind)


REFUSED = {
    "missing": "no such file",
    "folder": "is a folder",
    "not an image": "cannot decode",
    "truncated": "cannot decode",
    "bmp": "is a BMP image, not a JPEG or PNG",
    "tiny": f"smaller than {MIN_SIDE} px",
    "huge": "megapixels, more than 50",
    "grey": "is a grey image",
    "grey 16-bit": "is a grey image",
    "translucent": "translucent alpha",
}
NOTED = {
    "opaque alpha": "opaque alpha channel dropped",
    "16-bit": "16-bit PNG read at full precision",
    "palette": "palette image",
    "cmyk": "CMYK image converted",
    "grey as rgb": "R, G and B are equal",
    "overexposed": "clipped (overexposed)",
}


@pytest.mark.parametrize("kind", list(REFUSED))
def test_refused_photos_say_which_file_and_why(tmp_path, kind):
    path = _case(tmp_path, kind)
    with pytest.raises(PhotoError) as e:
        load_photo(path)
    message = str(e.value)
    assert message.startswith(f"{path}: ") and REFUSED[kind] in message, message
    assert "; " in message  # and what to do


@pytest.mark.parametrize("kind", list(NOTED))
def test_odd_photos_are_read_with_a_note(tmp_path, kind):
    path = _case(tmp_path, kind)
    photo, notes = load_photo(path)
    assert photo.shape == (3, 80, 80) and bool(torch.isfinite(photo).all())
    assert photo.min() >= 0 and photo.max() <= 1
    assert any(NOTED[kind] in n for n in notes), notes
    reference = srgb_to_linear(torch.from_numpy(_pattern(80, 80)).permute(2, 0, 1).float() / 255)
    if kind in ("opaque alpha", "16-bit"):  # same pixels as the plain photo
        assert float((photo - reference).abs().max()) < 1e-3


# -- tiles --------------------------------------------------------------------------------------


def _pointwise(photos: torch.Tensor) -> SVBRDF:
    """A fake generator whose maps at a pixel depend only on the photo at that pixel."""
    n = torch.cat([photos[:, :2] - 0.5, torch.ones_like(photos[:, :1])], 1)
    return SVBRDF(
        F.normalize(n, dim=1), photos, photos.mean(1, keepdim=True), photos.square(), validate=False
    )


@pytest.mark.parametrize("size", [32, 80, 100, 128])
def test_tiles_of_a_pointwise_model_equal_the_whole(size):
    """Blending tiles of a position-wise model gives the model on the whole photo: no seams anywhere,
    at tile borders included, for sizes the tiles cover evenly (128) or not (100)."""
    photo = torch.rand(3, size, size, generator=torch.Generator().manual_seed(size))
    calls = []

    def fn(x):
        calls.append(len(x))
        return _pointwise(x)

    tiled = tile_predict(fn, photo, 32, batch=4)
    whole = _pointwise(photo[None])
    assert sum(calls) == tile_count(size, 32) and max(calls) <= 4
    assert tiled.size == (size, size)
    for name in ("normal", "diffuse", "roughness", "specular"):
        assert float((getattr(tiled, name) - getattr(whole, name)).abs().max()) < 1e-5, name
    borders = sorted({16 * k for k in range(size // 16 + 1)} | {16 * k - 1 for k in range(1, size // 16 + 1)})
    borders = [b for b in borders if b < size]
    assert float((tiled.diffuse[..., borders] - whole.diffuse[..., borders]).abs().max()) < 1e-5


def test_tiles_of_different_answers_blend_smoothly():
    """A model that answers one random constant per tile: without blending the maps would jump by
    the whole difference at tile borders; the raised-cosine blend changes by little per pixel, and
    normals come out unit length."""
    g = torch.Generator().manual_seed(0)

    def fn(x):
        b = len(x)
        value = torch.rand(b, 3, 1, 1, generator=g).expand(b, 3, 32, 32)
        n = torch.cat([value[:, :2] - 0.5, torch.ones_like(value[:, :1])], 1)
        return SVBRDF(n / n.norm(dim=1, keepdim=True), value, value[:, :1], value, validate=False)

    tiled = tile_predict(fn, torch.zeros(3, 128, 128), 32)
    d = tiled.diffuse[0]
    step = max(float(d.diff(dim=1).abs().max()), float(d.diff(dim=2).abs().max()))
    spread = float(d.amax() - d.amin())
    assert spread > 0.4 and step < 0.15 * spread
    assert float((tiled.normal.norm(dim=1) - 1).abs().max()) < 1e-5


def test_tiles_refuse_a_photo_smaller_than_a_tile():
    with pytest.raises(DataError, match="smaller than a tile"):
        tile_predict(_pointwise, torch.rand(3, 20, 40), 32)


# -- conventions, re-rendering, relighting ---------------------------------------------------------


def test_directx_flips_y_only():
    n = random_svbrdf(1, 8, seed=2).normal
    d = to_directx(n)
    assert torch.equal(d[:, 1], -n[:, 1]) and torch.equal(d[:, 0], n[:, 0]) and torch.equal(d[:, 2], n[:, 2])
    assert torch.equal(to_directx(d), n)


def test_flash_consistency_of_the_true_maps_is_near_zero():
    """The oracle: the true maps against their own flash photo re-render it almost exactly; other
    maps do not. The photo may be given at another size (resampled to the maps')."""
    maps, photo = _flash_photo(64)
    fit = flash_consistency(maps, photo[0])
    assert float(fit.rmse[0]) < 0.01
    assert abs(float(fit.position[0, 2]) - 2.2) < 0.3
    wrong = flash_consistency(random_svbrdf(1, 64, seed=4), photo[0])
    assert float(wrong.rmse[0]) > 5 * float(fit.rmse[0])
    big = F.interpolate(photo, size=(128, 128), mode="nearest")
    assert float(flash_consistency(maps, big).rmse[0]) < 0.01


def test_relight_frames_circle_the_material():
    """Frames are finite, in [0, 1], and follow the light: at 0 degrees (light on +x) the right half
    of a flat material is brighter, at 180 degrees the left."""
    flat = SVBRDF.constant(1, 32)
    frames = relight_frames(flat, 8)
    assert frames.shape == (8, 3, 32, 32) and bool(torch.isfinite(frames).all())
    assert frames.min() >= 0 and frames.max() <= 1
    left, right = frames[..., :16].mean((1, 2, 3)), frames[..., 16:].mean((1, 2, 3))
    assert right[0] > left[0] and left[4] > right[4]


class _Pointwise:
    """A stand-in predictor at ``resolution`` (the _pointwise model)."""

    def __init__(self, resolution):
        self.resolution = resolution

    def predict(self, photo):
        return _pointwise(F.interpolate(photo[None], size=(self.resolution,) * 2, mode="area"))

    def predict_batch(self, photos):
        return _pointwise(photos)


def test_capture_one_notes_an_upsampled_square_and_writes_everything(tmp_path):
    """capture_one with a stand-in predictor at 80 px on a 90x64 photo: the 64 px square is
    upsampled (noted); the entry says so; every file is written."""
    path = _case(tmp_path, "small square")
    entry = capture_one(_Pointwise(80), path, tmp_path / "out", CaptureOptions(relit="none"))
    assert entry["status"] == "ok" and entry["square"] == MIN_SIDE and entry["maps"] == 80
    assert any("upsampled" in n for n in entry["notes"])
    assert entry["rmse"] is not None and 0 <= entry["rmse"] < 1
    assert {p.name for p in (tmp_path / "out").iterdir()} == {f"{n}.png" for n in OUTPUTS} | RECORDS


# -- the command ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def batch(tmp_path_factory, checkpoint):
    """One run on a batch: a rotated sRGB JPEG flash photo, a PNG one, and three bad files."""
    folder = tmp_path_factory.mktemp("capture-photos")
    _, photo = _flash_photo(96)
    pixels = (linear_to_srgb(photo[0]).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    exif = Image.Exif()
    exif[0x0112] = 8
    good = [
        _save(folder / "tiles.jpg", np.rot90(pixels, -1).copy(), quality=95, exif=exif),
        _save(folder / "tiles.png", pixels[:, 8:]),
    ]
    bad = [
        _case(folder, "not an image"),
        _case(folder, "grey"),
        _case(folder, "translucent"),
    ]
    out = tmp_path_factory.mktemp("capture-out") / "maps"
    paths = [good[0], bad[0], good[1], bad[1], bad[2]]
    result = run_cli("predict", *map(str, paths), "--checkpoint", str(checkpoint), "-o", str(out))
    return paths, good, bad, out, result


def test_command_captures_the_good_photos_and_reports_the_bad(batch):
    """Exit 1 (some failed); one error line per bad file, naming it; every output of the good ones;
    summary.json and the table give the re-rendering RMSE per photo and its median."""
    paths, good, bad, out, result = batch
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("svbrdf-train: error: ")]
    assert len(errors) == 3
    for line, path, why in zip(
        errors, bad, ("cannot decode", "grey image", "translucent alpha"), strict=True
    ):
        assert f"error: {path}: " in line and why in line
    assert f"svbrdf-train: note: {good[0]}: EXIF orientation 8 applied" in result.stderr
    assert "3 of 5 photo(s) failed" in result.stderr
    # the two photos share a stem: the second gets NAME-2
    folders = [out / "tiles", out / "tiles-2"]
    assert result.stdout.split() == [str(f) for f in folders]
    for folder in folders:
        names = {p.name for p in folder.iterdir()}
        assert names == {f"{n}.png" for n in OUTPUTS} | {"relit.gif"} | RECORDS
        assert read_image(folder / "normal.png").shape == (3, 32, 32)
        assert read_image(folder / "input.png").shape == (3, 32, 32)
        with Image.open(folder / "relit.gif") as gif:
            assert gif.n_frames > 1
        figure = read_image(folder / "rerender.png")
        assert figure.shape[2] > 3 * 32  # photo | re-rendering | error
    summary = json.loads((out / "summary.json").read_text())
    assert [e["status"] for e in summary["entries"]] == ["ok", "failed", "ok", "failed", "failed"]
    assert [e["photo"] for e in summary["entries"]] == [str(p) for p in paths]
    ok = [e for e in summary["entries"] if e["status"] == "ok"]
    rmse = [e["rmse"] for e in ok]
    assert all(isinstance(r, float) and 0 <= r < 1 for r in rmse)
    assert summary["median_rmse"] == pytest.approx(float(np.median(rmse)))
    assert all(len(e["flash"]["position"]) == 3 and e["flash"]["intensity"] >= 0 for e in ok)
    assert all(
        str(p) in e["error"] for p, e in zip(paths, summary["entries"], strict=True) if e["status"] != "ok"
    )
    assert f"{summary['median_rmse']:.4f}" in result.stderr and "median re-rendering RMSE" in result.stderr
    # The figure says what it measures where it is shown: the fit to this photo, not accuracy.
    assert "not how right they are" in result.stderr and "not how right" in summary["rmse_means"]


def test_command_exit_2_when_every_photo_fails(tmp_path, checkpoint):
    bad = [_case(tmp_path, "missing"), _case(tmp_path, "tiny")]
    result = _invoke(*bad, "--checkpoint", checkpoint, "-o", tmp_path / "maps")
    assert result.exit_code == 2
    assert "2 of 2 photo(s) failed" in result.stderr
    summary = json.loads((tmp_path / "maps" / "summary.json").read_text())
    assert summary["captured"] == 0 and summary["median_rmse"] is None


def test_command_tiles_directx_16_bit_and_relit_grid(tmp_path, checkpoint):
    """--tiles keeps the 96 px square at its size (25 tiles of 32 px); --normal-convention directx
    stores 1 - green of the OpenGL run; --bits 16; --relit png writes the grid instead of the GIF."""
    _, photo = _flash_photo(96)
    path = write_image(tmp_path / "shot.png", linear_to_srgb(photo[0]))
    common = [path, "--checkpoint", checkpoint, "--tiles", "--relit", "png"]
    gl = _invoke(*common, "-o", tmp_path / "gl")
    dx = _invoke(*common, "-o", tmp_path / "dx", "--normal-convention", "directx", "--bits", "16")
    assert gl.exit_code == 0 and dx.exit_code == 0, gl.stderr + dx.stderr
    entry = json.loads((tmp_path / "dx" / "summary.json").read_text())["entries"][0]
    assert entry["maps"] == 96 and entry["tiles"] == 25
    a = read_image(tmp_path / "gl" / "shot" / "normal.png")
    b = read_image(tmp_path / "dx" / "shot" / "normal.png")
    assert a.shape == b.shape == (3, 96, 96)
    assert float((b[1] - (1 - a[1])).abs().max()) <= 1 / 255
    assert float((b[[0, 2]] - a[[0, 2]]).abs().max()) <= 1 / 255
    assert (tmp_path / "dx" / "shot" / "diffuse.png").read_bytes()[24] == 16  # PNG bit depth
    assert (tmp_path / "gl" / "shot" / "diffuse.png").read_bytes()[24] == 8
    names = {p.name for p in (tmp_path / "dx" / "shot").iterdir()}
    assert "relit.png" in names and "relit.gif" not in names


def test_command_albedos_in_srgb_for_texture_tools(tmp_path, checkpoint):
    """Diffuse and specular are written sRGB-encoded by default (as texture tools expect), and
    linear with --albedo-encoding linear: the sRGB run's values are the linear run's through the
    sRGB curve, and each file's colour chunks say which; the other maps are unchanged."""
    from svbrdf_render import read_png_encoding

    _, photo = _flash_photo(64)
    path = write_image(tmp_path / "shot.png", linear_to_srgb(photo[0]))
    common = [path, "--checkpoint", checkpoint, "--relit", "none", "--bits", "16"]
    lin = _invoke(*common, "-o", tmp_path / "lin", "--albedo-encoding", "linear")
    srgb = _invoke(*common, "-o", tmp_path / "srgb")
    assert lin.exit_code == 0 and srgb.exit_code == 0, lin.stderr + srgb.stderr
    for name in ("diffuse", "specular"):
        a = read_image(tmp_path / "lin" / "shot" / f"{name}.png")
        b = read_image(tmp_path / "srgb" / "shot" / f"{name}.png")
        assert float((b - linear_to_srgb(a)).abs().max()) < 2e-3, name  # 16-bit steps, curve slope
        assert not torch.equal(a, b)
        assert read_png_encoding(tmp_path / "lin" / "shot" / f"{name}.png") == "linear"
        assert read_png_encoding(tmp_path / "srgb" / "shot" / f"{name}.png") == "srgb"
    for name in ("normal", "roughness"):
        assert torch.equal(
            read_image(tmp_path / "lin" / "shot" / f"{name}.png"),
            read_image(tmp_path / "srgb" / "shot" / f"{name}.png"),
        )


@pytest.mark.parametrize(
    "args, says",
    [
        (["--map-size", "64"], "--map-size goes with --tiles"),
        (["--tiles", "--map-size", "16"], "smaller than the model's resolution"),
        (["--crop", "1,2"], "X,Y,SIZE"),
        (["--crop", "0,0,-5"], "SIZE > 0"),
        (["--refine", "-1"], "--refine"),
        (["--refine", "x"], "--refine"),
        (["--refine-seconds", "2"], "--refine-seconds goes with --refine STEPS > 0"),
        (["--refine", "2", "--map-size", "8"], "smaller than 16 px"),
    ],
)
def test_command_bad_options_exit_2_and_write_nothing(tmp_path, checkpoint, args, says):
    path = write_image(tmp_path / "shot.png", torch.rand(3, 80, 80))
    result = _invoke(path, "--checkpoint", checkpoint, "-o", tmp_path / "maps", *args)
    assert result.exit_code == 2 and says in result.stderr, result.stderr
    assert not (tmp_path / "maps").exists()


def test_command_refines_with_a_checkpoint(tmp_path, checkpoint):
    """--refine 3: the smoke network's maps (32 px) refined at the square's own size (64 px);
    the entry records the refinement; relit.png has a row per version."""
    _, photo = _flash_photo(64)
    path = write_image(tmp_path / "shot.png", linear_to_srgb(photo[0]))
    result = _invoke(path, "--checkpoint", checkpoint, "-o", tmp_path / "maps", "--refine", 3, "--relit", "png")
    assert result.exit_code == 0, result.stderr
    assert read_image(tmp_path / "maps" / "shot" / "normal.png").shape == (3, 64, 64)
    summary = json.loads((tmp_path / "maps" / "summary.json").read_text())
    entry = summary["entries"][0]
    assert summary["refine"] == 3 and entry["maps"] == 64 and entry["refine"]["steps"] == 3
    assert entry["refine"]["rmse_refined"] == entry["rmse"]
    assert not any("upsampled" in n for n in entry["notes"])  # 64 px square, 32 px network


def test_the_photo_tool_has_one_home():
    """The photo tool is svbrdf-models' (svbrdf_train.capture, its alias, is gone: issue 48), and
    its names have one address: svbrdf-train passes none of them on (no ``__all__`` of its package
    or of its photo, sheet and error modules names them), and its data errors are svbrdf-models'
    DataError."""
    import importlib
    import sys

    import svbrdf_train
    from svbrdf_train import errors
    from svbrdf_train.data import photos, sheet

    sys.modules.pop("svbrdf_train.capture", None)
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("svbrdf_train.capture")
    borrowed = {"flash_consistency", "orient", "exif_orientation", "square_photo", "image_grid", "DataError"}
    for module in (svbrdf_train, photos, sheet, errors):
        assert not borrowed & set(module.__all__), module.__name__
    assert issubclass(errors.ShardError, DataError)


def test_help_states_the_limits_and_exit_codes():
    text = _invoke("--help").output
    assert f"under {MIN_SIDE} px" in text and f"over {MAX_PIXELS // 1_000_000} megapixels" in text
    assert "Exit status: 0 every photo captured; 1 some photos failed" in text and "2 every" in text
    assert "3 a file could not be written" in text
