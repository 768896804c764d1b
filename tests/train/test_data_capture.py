"""The capture of procedural photos beyond the des18 defaults: drawn distance and intensity,
white balance, JPEG (the torch round trip), the ``phone`` preset and ``data.capture``."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math

import pytest
import torch

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, render
from svbrdf_train.data.fitdata import build_datasets
from svbrdf_train.data.jpeg import CHROMINANCE_TABLE, LUMINANCE_TABLE, jpeg_roundtrip, quantisation_table
from svbrdf_train.data.procedural import ProceduralMaterials
from svbrdf_train.data.simulated_photo import (
    CAPTURE_PRESETS,
    PhotoSettings,
    _photos,
    photo_jpeg_quality,
    photo_scene,
)
from svbrdf_train.errors import RecipeError
from svbrdf_train.recipe import CAPTURES, load_recipe

PHONE = PhotoSettings.preset("phone")


# -- the defaults stay what they were ---------------------------------------------------------


def test_default_scenes_are_those_before_the_capture_settings():
    # The digest of the first 20 default scenes as photo_scene drew them before distance,
    # intensity, white balance and JPEG existed (same bytes of every photo on the CPU).
    scenes = [photo_scene(0, i).to_dict() for i in range(20)]
    digest = hashlib.sha256(json.dumps(scenes, sort_keys=True).encode()).hexdigest()
    assert digest == "3f1e3fca47a976c668a901eaaa49f2ebebb31535965501eda5cb9ca0269302c5"
    assert PhotoSettings.preset("des18") == PhotoSettings()
    assert all(photo_jpeg_quality(0, i) is None for i in range(50))


def test_the_new_settings_leave_the_des18_draws_alone():
    # Only what a setting governs changes: camera shift, flash offset, exposure and noise stay.
    other = PhotoSettings(intensity=(10, 21), white_balance=0.1, jpeg_probability=1.0)
    for i in range(20):
        a, b = photo_scene(0, i).to_dict(), photo_scene(0, i, other).to_dict()
        assert a["camera"] == b["camera"] and a["effects"] == b["effects"]
        assert a["lights"][0]["offset"] == b["lights"][0]["offset"]
    moved = photo_scene(0, 4, PhotoSettings(distance=(1.8, 3.7)))
    assert moved.effects == photo_scene(0, 4).effects
    assert torch.equal(moved.camera.position[:2], photo_scene(0, 4).camera.position[:2])


# -- ranges -----------------------------------------------------------------------------------


def test_phone_draws_stay_in_their_ranges():
    scenes = [photo_scene(3, i, PHONE) for i in range(400)]
    d = torch.tensor([float(s.camera.position[2]) for s in scenes], dtype=torch.float64)
    fov = torch.tensor([s.camera.fov for s in scenes], dtype=torch.float64)
    intensity = torch.tensor([float(s.lights[0].intensity) for s in scenes], dtype=torch.float64)
    assert d.min() >= 1.8 - 1e-5 and d.max() <= 3.7 + 1e-5
    assert intensity.min() >= 10 - 1e-4 and intensity.max() <= 21 + 1e-4
    # log-uniform: half the draws on either side of the geometric middle; both ends reached
    for x, low, high in ((d, 1.8, 3.7), (intensity, 10.0, 21.0)):
        share = float((x < math.sqrt(low * high)).double().mean())
        assert 0.42 < share < 0.58
        assert x.min() < low * 1.03 and x.max() > high / 1.03
    # the field of view frames the patch from the drawn distance
    assert torch.allclose(torch.tan(torch.deg2rad(fov) / 2) * d, torch.ones_like(d), atol=1e-5)
    # the intensity is drawn independently of the distance
    corr = torch.corrcoef(torch.stack([d.log(), intensity.log()]))[0, 1]
    assert abs(float(corr)) < 0.15
    for s in scenes:
        assert 0.0 <= s.effects["exposure"]["ev"] <= 0.5
        color = s.lights[0].color
        assert float(color[1]) == 1.0 and float((color - 1).abs().max()) <= 0.08 + 1e-6
    colors = torch.stack([s.lights[0].color for s in scenes])
    assert float(colors[:, 0].std()) > 0.03 and float(colors[:, 2].std()) > 0.03
    qualities = [photo_jpeg_quality(3, i, PHONE) for i in range(400)]
    coded = [q for q in qualities if q is not None]
    assert 0.42 < len(coded) / 400 < 0.58
    assert min(coded) == 75 and max(coded) == 95


def test_intensity_replaces_the_fixed_irradiance():
    s = PhotoSettings(intensity=(12.0, 12.0))
    for i in range(10):
        assert math.isclose(float(photo_scene(0, i, s).lights[0].intensity), 12.0, rel_tol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"distance": (3.0, 2.0)}, "distance"),
        ({"distance": (0.0, 2.0)}, "distance"),
        ({"intensity": (-1.0, 2.0)}, "intensity"),
        ({"intensity": (1.0, math.inf)}, "intensity"),
        ({"white_balance": -0.1}, "white_balance"),
        ({"white_balance": 1.0}, "white_balance"),
        ({"jpeg_probability": 1.5}, "jpeg_probability"),
        ({"jpeg_quality": (90, 80)}, "jpeg_quality"),
        ({"jpeg_quality": (0, 80)}, "jpeg_quality"),
        ({"jpeg_quality": (75.5, 80)}, "jpeg_quality"),
    ],
)
def test_bad_capture_settings_are_refused(kwargs, match):
    with pytest.raises(DataError, match=match):
        PhotoSettings(**kwargs)


def test_unknown_preset_is_refused():
    with pytest.raises(DataError, match="unknown capture 'dslr'.*des18, phone"):
        PhotoSettings.preset("dslr")


# -- photos -----------------------------------------------------------------------------------


def test_phone_photos_reproduce_and_batch_as_one_by_one():
    settings = dataclasses.replace(PHONE, gamma_probability=0.5)
    data = ProceduralMaterials(12, 40, seed=4, mix=0.5, photo=settings)
    batch = data.batch(range(12))
    again = ProceduralMaterials(12, 40, seed=4, mix=0.5, photo=settings).batch(range(12))
    one_by_one = torch.cat([data.batch([i])["input"] for i in range(12)])
    assert torch.equal(batch["input"], again["input"]) and torch.equal(batch["input"], one_by_one)
    x = batch["input"]
    assert torch.isfinite(x).all() and x.min() >= 0 and x.max() <= 1
    kinds = {(data.jpeg_quality(i) is not None, "gamma" in data.scene(i).effects) for i in range(12)}
    assert kinds == {(False, False), (False, True), (True, False), (True, True)}


def test_jpeg_photos_are_the_rendered_photos_round_tripped():
    data = ProceduralMaterials(10, 32, seed=1, photo=PhotoSettings(jpeg_probability=0.5, white_balance=0.1))
    batch = data.batch(range(10))
    for i in range(10):
        rendered = render(SVBRDF.unpack(batch["maps"][i : i + 1], validate=False), data.scene(i))
        q = data.jpeg_quality(i)
        expected = rendered if q is None else jpeg_roundtrip(rendered, q)
        assert torch.equal(batch["input"][i : i + 1], expected), i


def test_white_balance_colours_the_photo():
    from svbrdf_render import DES18_EFFECTS, Flash

    flat = SVBRDF.constant(1, 16)
    scene = photo_scene(0, 0, PhotoSettings(white_balance=0.1)).with_effects(DES18_EFFECTS)
    flash = scene.lights[0]
    white = dataclasses.replace(scene, lights=(Flash(flash.intensity, flash.offset),))
    ratio = render(flat, scene).mean(dim=(2, 3)) / render(flat, white).mean(dim=(2, 3))
    assert torch.allclose(ratio[0], flash.color, rtol=1e-5)
    assert float(flash.color[1]) == 1.0 and not torch.equal(flash.color, torch.ones(3))


def test_batched_render_takes_each_flash_colour():
    data = ProceduralMaterials(6, 24, seed=2, photo=PhotoSettings(white_balance=0.1))
    batch = data.batch(range(6))
    photos = _photos(batch["maps"], [data.scene(i) for i in range(6)])
    assert torch.allclose(photos, batch["input"], atol=1e-5)


def test_the_generators_photo_is_photo_effects():
    """svbrdf_render.PHOTO_EFFECTS is the one spelling of the photo the training data is made
    of: every photo_scene declares exactly those effects, and gamma for its share."""
    from svbrdf_render import PHOTO_EFFECTS

    settings = PhotoSettings(gamma_probability=0.5)
    declared = [tuple(photo_scene(0, i, settings).effects) for i in range(20)]
    assert set(declared) == {PHOTO_EFFECTS, (*PHOTO_EFFECTS, "gamma")}


def test_a_batch_with_vignetting_renders_as_one_by_one():
    """_photos runs the registry's image stages per photo but vignetting, which reads the camera
    and runs in the batched render: the very bytes of render(), whatever the fields of view."""
    from svbrdf_render import EFFECTS
    from svbrdf_train.data.simulated_photo import _IMAGE_STAGES

    data = ProceduralMaterials(3, 24, seed=2)
    batch = data.batch(range(3))
    scenes = [data.scene(i).with_effects({**data.scene(i).effects, "vignetting": {}}) for i in range(3)]
    assert len({s.camera.fov for s in scenes}) == 3
    image = [name for name, e in EFFECTS.items() if e.phase == "image"]
    assert _IMAGE_STAGES == ("exposure", "noise", "clip", "tone", "gamma") == tuple(image[1:])
    assert EFFECTS[image[0]].needs_camera  # vignetting, run first in the batch as render() runs it
    one_by_one = torch.cat(
        [render(SVBRDF.unpack(batch["maps"][k : k + 1], validate=False), s) for k, s in enumerate(scenes)]
    )
    assert torch.equal(_photos(batch["maps"], scenes), one_by_one)


# -- the JPEG round trip ----------------------------------------------------------------------


def _smooth(size: int = 64) -> torch.Tensor:
    y, x = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    return torch.stack([0.2 + 0.5 * x, 0.3 + 0.3 * y, 0.1 + 0.2 * x * y]).unsqueeze(0)


def test_jpeg_keeps_smooth_images_and_is_nearly_lossless_at_100():
    smooth = _smooth()
    for q in (75, 95):
        out = jpeg_roundtrip(smooth, q)
        assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
        assert float((out - smooth).abs().mean()) < 0.006 and float((out - smooth).abs().max()) < 0.04
    texture = torch.rand(2, 3, 40, 56, generator=torch.Generator().manual_seed(0))
    lossless = jpeg_roundtrip(texture, 100, subsampling=False)
    # what is left: 8-bit sRGB and YCbCr rounding (a few codes where linear steps are 0.009)
    assert float((lossless - texture).abs().max()) < 0.035
    assert float((lossless - texture).abs().mean()) < 0.004
    assert float((jpeg_roundtrip(texture, 30) - texture).abs().mean()) > 3 * float(
        (lossless - texture).abs().mean()
    )


def test_jpeg_errors_are_blocky_at_a_sharp_edge():
    edge = torch.zeros(1, 3, 64, 64)
    edge[..., 29:] = 0.8  # a vertical edge inside the blocks of columns 24-31
    err = (jpeg_roundtrip(edge, 50, subsampling=False) - edge).abs().amax(dim=(0, 1, 2))
    inside = err[24:32]
    assert float(inside.max()) > 0.01  # ringing in the edge's blocks
    assert float(err[:24].max()) == 0.0  # black blocks stay exactly black
    assert float(err[32:].max()) < float(inside.max()) / 3  # other blocks: a flat offset at most
    # per 8x8 block the error of the flat blocks right of the edge is one value
    flat = (jpeg_roundtrip(edge, 50, subsampling=False) - edge)[0, 0, :, 32:40]
    assert float(flat.max() - flat.min()) == 0.0


def test_jpeg_is_deterministic_batches_as_one_by_one_and_takes_odd_sizes():
    x = torch.rand(4, 3, 37, 53, generator=torch.Generator().manual_seed(1))
    qualities = [60, 75, 90, 100]
    a = jpeg_roundtrip(x, qualities)
    assert a.shape == x.shape and a.dtype == torch.float32
    assert torch.equal(a, jpeg_roundtrip(x, qualities))
    assert torch.equal(a, torch.cat([jpeg_roundtrip(x[k : k + 1], q) for k, q in enumerate(qualities)]))
    # values outside [0, 1] are clipped first, as a sensor clips them
    assert torch.equal(jpeg_roundtrip(x * 3 - 1, 80), jpeg_roundtrip((x * 3 - 1).clamp(0, 1), 80))


#: ITU T.81 Annex K.1, as the standard prints them (quality 50, row major): the luminance table
#: (K.1) on the left of each row, the chrominance table (K.2) on the right.
_ANNEX_K1 = """
    16  11  10  16  24  40  51  61    17  18  24  47  99  99  99  99
    12  12  14  19  26  58  60  55    18  21  26  66  99  99  99  99
    14  13  16  24  40  57  69  56    24  26  56  99  99  99  99  99
    14  17  22  29  51  87  80  62    47  66  99  99  99  99  99  99
    18  22  37  56  68 109 103  77    99  99  99  99  99  99  99  99
    24  35  55  64  81 104 113  92    99  99  99  99  99  99  99  99
    49  64  78  87 103 121 120 101    99  99  99  99  99  99  99  99
    72  92  95  98 112 100 103  99    99  99  99  99  99  99  99  99
"""


def test_quantisation_tables_are_the_standard_ones_as_tuples_of_ints():
    rows = [tuple(int(v) for v in line.split()) for line in _ANNEX_K1.strip().splitlines()]
    for table, expected in ((LUMINANCE_TABLE, [r[:8] for r in rows]), (CHROMINANCE_TABLE, [r[8:] for r in rows])):
        assert len(table) == 8 and all(type(row) is tuple and len(row) == 8 for row in table)
        assert all(type(v) is int for row in table for v in row)
        assert table == tuple(expected)


def test_quantisation_tables_scale_as_libjpeg():
    assert torch.equal(quantisation_table(LUMINANCE_TABLE, 50), torch.tensor(LUMINANCE_TABLE).float())
    assert torch.equal(quantisation_table(LUMINANCE_TABLE, 100), torch.ones(8, 8))
    assert float(quantisation_table(LUMINANCE_TABLE, 75)[0, 0]) == 8  # (16 * 50 + 50) // 100
    assert float(quantisation_table(LUMINANCE_TABLE, 1).max()) == 255
    with pytest.raises(DataError, match="quality"):
        quantisation_table(LUMINANCE_TABLE, 0)
    with pytest.raises(DataError, match=r"\(B, 3, H, W\)"):
        jpeg_roundtrip(torch.rand(3, 8, 8), 80)


# -- the recipe -------------------------------------------------------------------------------


def test_recipe_capture_names_the_presets():
    assert set(CAPTURES) == set(CAPTURE_PRESETS)
    assert load_recipe("ours", "smoke").data.capture == "des18"


def test_data_capture_photographs_training_and_validation_alike():
    train, val = build_datasets(load_recipe("ours", "smoke", {"data.capture": "phone"}))
    assert isinstance(train, ProceduralMaterials) and isinstance(val, ProceduralMaterials)
    assert train.photo == val.photo == PHONE
    train, val = build_datasets(load_recipe("ours", "smoke"))
    assert train.photo == val.photo == PhotoSettings()
    mixed = load_recipe(
        "ours", "smoke", {"data.source": "mix", "data.mix": [{"source": "procedural", "weight": 1}],
                          "data.capture": "phone"}
    )
    train, _ = build_datasets(mixed)
    assert train.sources[0].photo == PHONE


def test_a_bad_capture_is_refused_naming_the_field():
    with pytest.raises(RecipeError, match=r"capture.*'des18', 'phone'.*'dslr'"):
        load_recipe("ours", "smoke", {"data.capture": "dslr"})


def test_data_make_records_the_capture(tmp_path):
    from click.testing import CliRunner

    from svbrdf_train.cli import cli
    from svbrdf_train.data.shards import ShardDataset, inspect_shard

    out = tmp_path / "phone.h5"
    args = ["data", "make", "--count", 3, "--resolution", 16, "--capture", "phone", "--out", out]
    result = CliRunner().invoke(cli, list(map(str, args)))
    assert result.exit_code == 0, result.output
    info = inspect_shard(out)
    assert info.attrs["capture"] == "phone"
    assert json.loads(info.attrs["photo"]) == json.loads(json.dumps(dataclasses.asdict(PHONE)))
    expected = ProceduralMaterials(3, 16, 0, photo=PHONE).batch([0, 1, 2])["input"]
    got = torch.stack([ShardDataset(out)[i]["input"] for i in range(3)])
    assert float((got - expected).abs().max()) <= 0.5 / 255 + 1e-6
