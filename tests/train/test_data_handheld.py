"""Issue 46's training photos: the ``handheld`` capture (LED beside the lens, beam, vignetting,
tone, the camera off-centre), kind-balanced materials and the albedo prior."""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest
import torch

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, render
from svbrdf_train.data.real.kinds import kind_weights, material_kind
from svbrdf_train.data.real.strip_bank import MaterialBank
from svbrdf_train.data.real.strips import PRIOR_FACTOR, MaterialStrips
from svbrdf_train.data.simulated_photo import CAPTURE_PRESETS, PhotoSettings, photo_scene
from svbrdf_train.recipe import DataSection

HANDHELD = PhotoSettings.preset("handheld")


def test_handheld_photos_declare_the_phones_effects_within_their_ranges():
    p = CAPTURE_PRESETS["handheld"]
    for i in range(40):
        fx = photo_scene(3, i, HANDHELD).effects
        assert p["beam_exponent"][0] <= fx["beam"]["exponent"] <= p["beam_exponent"][1]
        assert p["vignetting"][0] <= fx["vignetting"]["strength"] <= p["vignetting"][1]
        assert p["tone_power"][0] <= fx["tone"]["power"] <= p["tone_power"][1]
        assert p["tone_shoulder"][0] <= fx["tone"]["shoulder"] <= p["tone_shoulder"][1]
    for name in ("des18", "phone"):
        fx = photo_scene(3, 0, PhotoSettings.preset(name)).effects
        assert not {"beam", "vignetting", "tone"} & set(fx)


def test_the_led_sits_on_a_ring_beside_the_lens_and_the_camera_anywhere_in_the_central_half():
    offsets = [float(photo_scene(1, i, HANDHELD).lights[0].offset[:2].norm()) for i in range(200)]
    shifts = [float(photo_scene(1, i, HANDHELD).camera.position[:2].norm()) for i in range(200)]
    assert 0.08 - 1e-6 <= min(offsets) and max(offsets) <= 0.3 + 1e-6
    assert min(offsets) < 0.12 and max(offsets) > 0.26  # the whole ring is used
    assert max(shifts) <= 0.6 + 1e-6 and max(shifts) > 0.5


def test_the_new_draws_move_no_draw_of_the_other_captures():
    phone = PhotoSettings.preset("phone")
    more = PhotoSettings(**{**CAPTURE_PRESETS["phone"], "beam_exponent": (1.0, 2.0), "tone_power": (0.9, 1.1)})
    for i in range(5):
        a, b = photo_scene(0, i, phone), photo_scene(0, i, more)
        assert torch.equal(a.camera.position, b.camera.position)
        assert torch.equal(a.lights[0].offset, b.lights[0].offset)
        assert a.effects["exposure"] == b.effects["exposure"] and a.effects["noise"] == b.effects["noise"]


def test_a_handheld_photo_is_finite_and_in_range_forward_and_backward():
    maps = SVBRDF.constant(1, 32, diffuse=(0.0, 0.5, 0.95), roughness=0.02, specular=(0.9, 0.9, 0.9))
    maps = SVBRDF(*(t.requires_grad_(True) for t in maps.maps().values()))
    for i in range(6):
        photo = render(maps, photo_scene(2, i, HANDHELD))
        photo.sum().backward()
        assert torch.isfinite(photo).all()
        assert 0 <= float(photo.detach().min()) and float(photo.detach().max()) <= 1.0 + 1e-6
        assert all(torch.isfinite(t.grad).all() for t in maps.maps().values())


@pytest.mark.parametrize(
    "field,value",
    [("beam_exponent", (3.0, 1.0)), ("vignetting", (0.0, 1.5)), ("tone_power", (0.1, 1.0)),
     ("tone_shoulder", (-1.0, 0.0)), ("flash_offset_min", 0.5)],
)
def test_handheld_ranges_out_of_bounds_are_refused(field, value):
    with pytest.raises(DataError, match=field):
        PhotoSettings(**{**CAPTURE_PRESETS["handheld"], field: value})


@pytest.mark.parametrize(
    "name,kind",
    [("3dcreator_Bricks057", "brick"), ("texhaven_plaster_brick_01", "plaster/concrete"),
     ("texhaven_moss_wood", "wood"), ("texhaven_sandstone_blocks_04", "stone"),
     ("texhaven_brown_mud_rocks_01", "ground"), ("osm2world_CorrugatedSteel005", "metal"),
     ("texhaven_grey_roof_tiles", "tiles"), ("osm2world_Snow006", "ground"), ("x_Chip001", "other")],
)
def test_a_materials_kind_is_read_from_its_name(name, kind):
    assert material_kind(name) == kind


def test_kind_weights_give_a_kind_the_square_root_of_its_size():
    names = [f"rock_{i}" for i in range(16)] + [f"plank_{i}" for i in range(4)] + ["paper_1"]
    w = kind_weights(names)
    share = collections.defaultdict(float)
    for n, v in zip(names, w):
        share[material_kind(n)] += v
    assert share["stone"] == pytest.approx(4.0) and share["wood"] == pytest.approx(2.0)
    assert share["paper"] == pytest.approx(1.0)


def _bank(levels) -> MaterialBank:
    maps = []
    for level in levels:
        m = np.zeros((10, 32, 32), np.uint8)
        m[0:2], m[2] = 128, 255
        m[3:6], m[6], m[7:10] = round(level * 255), 128, 10
        maps.append(m)
    return MaterialBank(tuple(f"m{i}" for i in range(len(levels))), tuple(maps), "test bank")


def test_weights_draw_materials_in_proportion_and_name_them():
    data = MaterialStrips(_bank([0.2, 0.2, 0.2]), 3000, 32, weights=[1.0, 2.0, 0.0])
    drawn = collections.Counter(data.placement(i).material for i in range(3000))
    assert drawn[2] == 0 and drawn[1] / drawn[0] == pytest.approx(2.0, rel=0.15)
    item = data[5]
    assert item["name"] == f"strip:m{data.placement(5).material}"
    with pytest.raises(DataError, match="weights"):
        MaterialStrips(_bank([0.2, 0.2]), 10, 32, weights=[1.0])


def test_the_albedo_prior_sets_the_brightness_mix_not_the_sources_level():
    bright, dark = 0.6, 0.06
    data = MaterialStrips(_bank([bright, dark]), 400, 32, albedo_prior=(0.15, 0.5))
    factors = [(data.placement(i).material, data.placement(i).albedo) for i in range(400)]
    for m, f in factors:
        assert PRIOR_FACTOR[0] <= f <= PRIOR_FACTOR[1]
    bright_f = [f for m, f in factors if m == 0]
    dark_f = [f for m, f in factors if m == 1]
    assert np.median(bright_f) < 0.6 and np.median(dark_f) > 1.6  # both pulled towards 0.15
    means = [float(data.maps(i).diffuse.mean()) for i in range(0, 400, 7)]
    plain = MaterialStrips(_bank([bright, dark]), 400, 32)
    assert all(0.8 <= plain.placement(i).albedo <= 1.25 for i in range(0, 400, 7))
    plain_means = [float(plain.maps(i).diffuse.mean()) for i in range(0, 400, 7)]
    # the two sources' levels (0.06 and 0.6, x0.8-1.25) against the prior's pull to 0.15
    assert np.std(np.log(means)) < 0.6 * np.std(np.log(plain_means))
    assert abs(np.mean(np.log(means)) - math.log(0.15)) < abs(np.mean(np.log(plain_means)) - math.log(0.15))


def test_balance_and_the_prior_need_a_materials_source():
    with pytest.raises(ValueError, match="materials source"):
        DataSection(source="procedural", balance="kind")
    with pytest.raises(ValueError, match="albedo_prior"):
        DataSection(source="materials", albedo_prior=(1.5, 0.5))
    section = DataSection(source="mix", mix=({"source": "procedural", "weight": 1.0},
                                             {"source": "materials", "weight": 1.0}), balance="kind")
    assert section.balance == "kind" and math.isfinite(1.0)
