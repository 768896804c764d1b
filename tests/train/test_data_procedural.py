"""Procedural materials and their simulated phone photos: determinism, ranges, physics of the
maps, the photo scene, batching and DataLoader workers."""

from __future__ import annotations

import hashlib
import importlib
import math
import pkgutil
import subprocess
import sys

import pytest
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, Camera, PointLight, Scene, render
from svbrdf_train.data.procedural import (
    FAMILIES,
    GENERATOR_VERSION,
    ProceduralMaterials,
    families,
    material,
    materials,
)
from svbrdf_train.data.procedural.families import family_fields
from svbrdf_train.data.procedural.maps import _normals
from svbrdf_train.data.simulated_photo import PhotoSettings, photo_scene

#: Families with metal in them: the metal family, and painted and rusted metal.
METALLIC = ("metal", "rusted")
DIELECTRICS = [f for f in FAMILIES if f not in METALLIC]


def _digest(*tensors: torch.Tensor) -> str:
    h = hashlib.sha256()
    for t in tensors:
        h.update(t.contiguous().numpy().tobytes())
    return h.hexdigest()


def _check_maps(m: SVBRDF) -> None:
    assert m.dtype == torch.float32
    for name in ("diffuse", "roughness", "specular"):
        t = getattr(m, name)
        assert torch.isfinite(t).all() and t.min() >= 0 and t.max() <= 1, name
    assert torch.isfinite(m.normal).all()
    assert torch.allclose(m.normal.norm(dim=1), torch.ones(()), atol=1e-5)
    assert (m.normal[:, 2] > 0).all()


def test_the_issue_families_exist():
    assert set(FAMILIES) >= {"stone", "tiles", "cells", "wood", "metal", "fabric"}
    assert set(FAMILIES) >= {"plaster", "rusted", "bark", "rock"}  # generator 3
    assert isinstance(GENERATOR_VERSION, str) and GENERATOR_VERSION == "3"


def test_each_family_module_registers_its_family_in_the_drawing_order():
    # One module per family, registered where it is written. A sample picks its family by its
    # position in FAMILIES, so generator 3's order is part of its output.
    modules = {m.name for m in pkgutil.iter_modules(families.__path__)} - {"base", "drawing"}
    assert modules == set(FAMILIES) == set(families.FAMILY_TABLE)
    for name in FAMILIES:
        module = importlib.import_module(f"svbrdf_train.data.procedural.families.{name}")
        assert families.FAMILY_TABLE[name].draw is module.draw
        assert families.FAMILY_TABLE[name].fields is module.fields
    order = ("stone", "tiles", "cells", "wood", "metal", "fabric", "plaster", "rusted", "bark", "rock")
    assert FAMILIES == order


def test_a_family_name_registers_once():
    with pytest.raises(DataError, match="'stone' is registered twice"):
        families.register(families.FAMILY_TABLE["stone"])
    assert len(families.FAMILY_TABLE) == len(FAMILIES)


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_has_valid_varied_maps(family):
    m, names = materials(0, range(6), 40, family=family)
    assert names == [family] * 6 and m.shape == (6, 40, 40)
    _check_maps(m)
    # A pattern, not a flat fill, and six different materials.
    assert (m.pack().std(dim=(2, 3)).amax(dim=1) > 1e-2).all()
    assert len({_digest(m.pack()[k]) for k in range(6)}) == 6


def test_mixtures_blend_two_families_through_a_mask():
    m, names = materials(1, range(8), 40, mix=1.0)
    assert all("+" in n and all(p in FAMILIES for p in n.split("+")) for n in names)
    _check_maps(m)
    # Forced metal in stone: the specular map holds both a metal and a dielectric.
    m, name = material(0, 2, 64, family="stone+metal")
    assert name == "stone+metal"
    _check_maps(m)
    mean = m.specular.mean(dim=1)
    assert (mean < 0.07).float().mean() > 0.05 and (mean > 0.45).float().mean() > 0.05


def test_same_seed_same_bytes_other_seed_or_index_other_material():
    a = ProceduralMaterials(8, 32, seed=5, mix=0.5)
    b = ProceduralMaterials(8, 32, seed=5, mix=0.5)
    for i in (0, 3, 6):
        x, y = a[i], b[i]
        assert _digest(x["maps"], x["input"]) == _digest(y["maps"], y["input"])
        assert x["name"] == f"procedural:5:{i}"
    other = ProceduralMaterials(8, 32, seed=6, mix=0.5)
    assert not torch.equal(a[3]["maps"], other[3]["maps"])
    assert not torch.equal(a[3]["maps"], a[4]["maps"])


def test_same_bytes_in_another_process():
    code = (
        "import hashlib;from svbrdf_train.data.procedural import ProceduralMaterials as P;"
        "s=P(4,24,seed=9,mix=0.5).batch([1,2]);h=hashlib.sha256();"
        "[h.update(s[k].contiguous().numpy().tobytes()) for k in ('maps','input')];print(h.hexdigest())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    s = ProceduralMaterials(4, 24, seed=9, mix=0.5).batch([1, 2])
    assert out.stdout.strip() == _digest(s["maps"], s["input"])


@pytest.mark.parametrize("resolution", [40, 37])
def test_batch_equals_items_bit_for_bit(resolution):
    data = ProceduralMaterials(10, resolution, seed=2, mix=0.5)
    assert any("+" in data.family(i) for i in range(10))  # mixtures are in the batch too
    batch = data.batch([3, 4, 0, 9, 7, 1])
    for k, i in enumerate([3, 4, 0, 9, 7, 1]):
        item = data[i]
        assert torch.equal(batch["maps"][k], item["maps"]), i
        assert torch.equal(batch["input"][k], item["input"]), i
        assert batch["name"][k] == item["name"]
    # Another composition of the batch: still the same samples.
    again = data.batch([9, 3])
    assert torch.equal(again["maps"][0], batch["maps"][3])
    assert torch.equal(again["input"][1], batch["input"][0])


def test_chunking_does_not_change_the_bytes(monkeypatch):
    import svbrdf_train.data.procedural.maps as procedural_maps

    data = ProceduralMaterials(6, 24, seed=7, mix=0.5)
    whole = data.batch(range(6))
    monkeypatch.setattr(procedural_maps, "_CHUNK_PIXELS", 2 * 24 * 24)  # chunks of two samples
    chunked = data.batch(range(6))
    assert torch.equal(whole["maps"], chunked["maps"]) and torch.equal(whole["input"], chunked["input"])


def test_thread_count_does_not_change_the_bytes():
    threads = torch.get_num_threads()
    data = ProceduralMaterials(4, 48, seed=4)
    try:
        torch.set_num_threads(1)
        one = data.batch([0, 1, 2, 3])
        torch.set_num_threads(2)
        two = data.batch([0, 1, 2, 3])
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(one["maps"], two["maps"]) and torch.equal(one["input"], two["input"])


def _luminance(rgb: torch.Tensor) -> torch.Tensor:
    return 0.2126 * rgb[:, 0] + 0.7152 * rgb[:, 1] + 0.0722 * rgb[:, 2]


@pytest.mark.parametrize("family", DIELECTRICS)
def test_dielectrics_have_grey_low_specular(family):
    # Everywhere but on the metal studs that some tiles carry (see the next tests).
    f = family_fields(family, list(range(12)), 32)
    dielectric = (
        f.parts["stud"][:, 0] == 0
        if "stud" in f.parts
        else torch.ones_like(f.roughness[:, 0], dtype=torch.bool)
    )
    spread = (f.specular.amax(dim=1) - f.specular.amin(dim=1))[dielectric]
    assert spread.max() < 1e-6
    level = f.specular[:, 0][dielectric]
    assert 0.02 <= level.min() and level.max() <= 0.065
    if family != "tiles":  # and so in the samples themselves
        m, _ = materials(3, range(8), 32, family=family)
        assert (m.specular.amax(dim=1) - m.specular.amin(dim=1)).max() < 1e-6
        assert 0.02 <= m.specular.min() and m.specular.max() <= 0.065


def test_metals_have_coloured_specular_above_dielectrics_and_dark_diffuse():
    m, _ = materials(3, range(24), 32, family="metal")
    level = _luminance(m.specular).mean(dim=(1, 2))
    assert (level >= 0.08).all() and (m.specular.max() <= 1)  # above every dielectric (<= 0.06)
    assert (level >= 0.5).any() and (level < 0.4).any()  # bright metals, and dark (tarnished) ones
    assert m.diffuse.mean(dim=(1, 2, 3)).max() < 0.07
    spread = (m.specular.amax(dim=1) - m.specular.amin(dim=1)).mean(dim=(1, 2))
    assert (spread > 0.2).any()  # gold, copper, brass or anodised among them: coloured, not grey


def test_some_tiles_carry_metal_studs_on_their_corners():
    f = family_fields("tiles", list(range(40)), 64)
    stud = f.parts["stud"][:, 0]
    with_studs = [k for k in range(40) if (stud[k] > 0.99).any()]
    assert 3 <= len(with_studs) <= 30  # some, not all
    for k in with_studs:
        on = stud[k] > 0.99
        level = _luminance(f.specular[k : k + 1])[0]
        assert level[on].min() >= 0.08  # metal
        assert f.diffuse[k][:, on].max() <= 0.03  # dark diffuse
        assert f.height[k, 0][on].mean() > f.height[k, 0][stud[k] == 0].mean()  # raised
        assert (stud[k] > 0.99).float().mean() < 0.2  # small
    # Studs sit where four tiles meet: on the grout lines.
    k = with_studs[0]
    near = F.max_pool2d(f.parts["grout"][k : k + 1], 9, stride=1, padding=4)[0, 0]
    assert (near[stud[k] > 0.99] > 0.5).float().mean() > 0.5


def test_grout_is_rougher_and_lower_than_the_tiles():
    f = family_fields("tiles", list(range(6)), 96)
    grout = f.parts["grout"]
    for k in range(6):
        in_grout, on_tile = grout[k] > 0.95, grout[k] < 0.05
        assert in_grout.any() and on_tile.any()
        assert f.roughness[k][in_grout].mean() > f.roughness[k][on_tile].mean() + 0.1
        assert f.roughness[k][in_grout].min() > f.roughness[k][on_tile].max()
        assert f.height[k][in_grout].mean() < f.height[k][on_tile].mean()


def test_painted_and_rusted_metal_is_metal_only_where_bare():
    f = family_fields("rusted", list(range(16)), 64)
    metal, rust, paint = f.parts["metal"][:, 0], f.parts["rust"][:, 0], f.parts["paint"][:, 0]
    assert torch.allclose(metal + rust + paint, torch.ones(()), atol=1e-5)  # the three layers
    level = _luminance(f.specular)
    spread = f.specular.amax(dim=1) - f.specular.amin(dim=1)
    bare = [k for k in range(16) if (metal[k] > 0.99).any()]
    rusty = [k for k in range(16) if (rust[k] > 0.99).any()]
    painted = [k for k in range(16) if (paint[k] > 0.99).any()]
    assert len(bare) >= 8 and len(rusty) >= 8 and len(painted) >= 4
    for k in bare:  # bare metal: coloured specular above every dielectric, dark diffuse
        on = metal[k] > 0.999
        assert level[k][on].min() >= 0.08 and f.diffuse[k][:, on].max() <= 0.035
    for k in range(16):  # rust and paint: grey dielectric specular
        coat = (rust[k] == 1) | (paint[k] == 1)
        assert spread[k][coat].max() < 1e-6
        assert 0.025 <= f.specular[k, 0][coat].min() and f.specular[k, 0][coat].max() <= 0.05
    for k in rusty:  # rust: orange-brown (red above blue), rough
        on = rust[k] > 0.99
        rgb = f.diffuse[k][:, on].mean(dim=1)
        assert rgb[0] > rgb[2] and f.roughness[k, 0][on].mean() >= 0.65
    for k in painted:  # paint lies on the metal, chipped: raised above the bare chips
        chipped = metal[k] > 0.99
        if chipped.any():
            assert f.height[k, 0][paint[k] > 0.99].mean() > f.height[k, 0][chipped].mean()


@pytest.mark.parametrize(("family", "part"), [("plaster", "pore"), ("bark", "furrow"), ("rock", "crevice")])
def test_recessed_parts_are_rougher_and_lower(family, part):
    f = family_fields(family, list(range(12)), 96)
    mask = f.parts[part][:, 0]
    found = 0
    for k in range(12):
        inside, outside = mask[k] > 0.95, mask[k] < 0.05
        if inside.sum() < 10 or outside.sum() < 10:
            continue
        found += 1
        rough, height = f.roughness[k, 0], f.height[k : k + 1]
        assert rough[inside].mean() > rough[outside].mean() + 0.05, k
        # Lower than what lies around (rock's broad relief dwarfs its crevices' depth).
        around = F.avg_pool2d(height, 15, stride=1, padding=7, count_include_pad=False)
        below = (around - height)[0, 0]
        assert below[inside].mean() > below[outside].mean(), k
    assert found >= 5


@pytest.mark.parametrize("family", ["plaster", "bark", "rock"])
def test_rough_surfaces_are_rough_and_not_shiny(family):
    m, _ = materials(5, range(12), 48, family=family)
    assert m.roughness.mean(dim=(1, 2, 3)).min() >= 0.55
    assert m.diffuse.mean(dim=(1, 2, 3)).max() <= 0.7


def test_plaster_is_nearly_flat_and_rock_strongly_relieved():
    from svbrdf_train.data.stats import slope_mean

    plaster, _ = _packed_maps("plaster")
    rock, _ = _packed_maps("rock")
    assert float(slope_mean(plaster).median()) < 0.2 < float(slope_mean(rock).median())


def test_relief_and_saturation_spread_over_flat_to_relieved_and_grey_to_saturated():
    # Generator 3: a relief scale flattens some materials of any family nearly flat while
    # others keep a strong relief, and the albedo's chroma spans greyish to saturated.
    from svbrdf_train.data.stats import diffuse_saturation, slope_p90

    m, _ = materials(0, range(64), 32)
    steep, sat = slope_p90(m.pack()), diffuse_saturation(m.pack())
    flat = float((steep < 0.03).float().mean())
    assert 0.05 <= flat <= 0.5 and float((steep > 0.6).float().mean()) >= 0.05
    assert float(torch.quantile(sat, 0.1)) < 0.15 and float(torch.quantile(sat, 0.9)) > 0.65
    assert float(sat.max()) < 1  # boosted chroma eases off before a pure colour
    # Even the most relieved family has nearly flat members, and strongly relieved ones.
    rock, _ = materials(6, range(16), 32, family="rock")
    rock_steep = slope_p90(rock.pack())
    assert float(rock_steep.min()) < 0.05 and float(rock_steep.max()) > 0.6


def _packed_maps(family: str):
    m, names = materials(6, range(12), 64, family=family)
    return m.pack(), names


def test_the_new_families_batch_as_they_compute_alone():
    # Batched with each other, mixed with the old families, and alone: the same bytes.
    families = ["plaster", "rusted", "bark", "rock", "stone"]
    data = ProceduralMaterials(12, 40, seed=11, families=families, mix=0.5)
    indices = list(range(12))
    batch = data.batch(indices)
    assert {n for i in indices for n in data.family(i).split("+")} >= {"plaster", "rusted", "bark", "rock"}
    for k in indices:
        item = data[k]
        assert torch.equal(batch["maps"][k], item["maps"]) and torch.equal(batch["input"][k], item["input"])
    for family in ("plaster", "rusted", "bark", "rock"):
        many, _ = materials(4, range(5), 33, family=family)
        one, _ = materials(4, [3], 33, family=family)
        assert torch.equal(many.pack()[3], one.pack()[0]), family


def test_normals_follow_the_opengl_convention():
    # Heights on a grid with a one-pixel margin; x grows to the right, y grows upwards (row 0 on top).
    n = 16
    t = ((torch.arange(n + 2, dtype=torch.float32) - 1) * 2 + 1) / n - 1
    x = t.view(1, 1, 1, -1).expand(1, 1, n + 2, n + 2)
    y = (-t).view(1, 1, -1, 1).expand(1, 1, n + 2, n + 2)
    right = _normals(0.5 * x)  # rising to the right: tilted towards -x
    assert torch.allclose(
        right, torch.tensor([-0.5, 0.0, 1.0]).div(math.sqrt(1.25)).view(1, 3, 1, 1), atol=1e-6
    )
    up = _normals(0.5 * y)  # rising towards the top of the image: tilted towards -y
    assert torch.allclose(up, torch.tensor([0.0, -0.5, 1.0]).div(math.sqrt(1.25)).view(1, 3, 1, 1), atol=1e-6)
    # The renderer agrees: a slope that faces left is brighter lit from the left.
    m = SVBRDF(
        right[:, :, :, :].expand(1, 3, n, n).contiguous(),
        torch.full((1, 3, n, n), 0.5),
        torch.full((1, 1, n, n), 0.5),
        torch.full((1, 3, n, n), 0.04),
    )
    lit = [
        render(m, Scene(Camera(), (PointLight(torch.tensor([sx, 0.0, 2.0]), 10.0),))).mean()
        for sx in (-2.0, 2.0)
    ]
    assert lit[0] > 1.5 * lit[1]


def test_patterns_do_not_depend_on_the_resolution():
    m64, _ = materials(8, range(12), 64)
    m32, _ = materials(8, range(12), 32)
    pooled = F.avg_pool2d(m64.diffuse, 2)
    assert (pooled.mean(dim=(2, 3)) - m32.diffuse.mean(dim=(2, 3))).abs().max() < 0.02


@pytest.mark.parametrize("resolution", [48, 37, 64])
def test_any_resolution(resolution):
    s = ProceduralMaterials(3, resolution, seed=1, mix=0.5).batch([0, 1, 2])
    assert s["maps"].shape == (3, 10, resolution, resolution)
    assert s["input"].shape == (3, 3, resolution, resolution)
    assert s["maps"].dtype == s["input"].dtype == torch.float32


def test_photos_are_clipped_and_exposed():
    s = ProceduralMaterials(12, 48, seed=0).batch(range(12))
    photo = s["input"]
    assert photo.min() >= 0 and photo.max() <= 1
    per_sample = photo.mean(dim=(1, 2, 3))
    assert (per_sample > 0.01).all()  # not black
    assert ((photo == 1).float().mean(dim=(1, 2, 3)) < 0.5).all()  # not blown out
    assert per_sample.median() > 0.05


def test_photo_reproduces_with_the_seed_and_changes_with_another():
    m, _ = material(0, 5, 32)
    a = render(m, photo_scene(0, 5))
    b = render(m, photo_scene(0, 5))
    c = render(m, photo_scene(1, 5))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert not torch.equal(a, render(m, photo_scene(0, 6)))


def test_photo_scene_declares_exactly_the_phone_effects():
    shading = ["diffuse", "specular", "fresnel", "masking", "cosine", "falloff"]
    for i in range(10):
        scene = photo_scene(0, i)
        assert list(scene.effects) == shading + ["exposure", "noise", "clip"]
        fov = scene.camera.fov
        distance = 1 / math.tan(math.radians(fov) / 2)
        assert 40 <= fov <= 58
        # The camera is held off the patch's axis (by 0.03-0.3 half-widths), at the height
        # that frames the patch.
        assert math.isclose(float(scene.camera.position[2]), distance, rel_tol=1e-6)
        assert 0.03 - 1e-6 <= float(scene.camera.position[:2].norm()) <= 0.3 + 1e-6
        (flash,) = scene.lights
        assert float(flash.offset.norm()) <= 0.2 + 1e-6 and float(flash.offset[2]) == 0
        assert math.isclose(float(flash.intensity), math.pi * distance**2, rel_tol=1e-6)
        assert -0.75 <= scene.effects["exposure"]["ev"] <= 0.75
    seeds = {photo_scene(0, i).effects["noise"]["seed"] for i in range(10)}
    assert len(seeds) == 10
    gamma = photo_scene(0, 3, PhotoSettings(gamma_probability=1.0, gamma=2.0))
    assert list(gamma.effects) == shading + ["exposure", "noise", "clip", "gamma"]
    assert gamma.effects["gamma"]["gamma"] == 2.0
    # The gamma draw does not move the other draws: the same flash with or without it.
    assert gamma.effects["noise"] == photo_scene(0, 3).effects["noise"]


def test_the_highlight_lies_off_centre_under_camera_and_flash():
    # A flat, dark, glossy surface: the highlight is the mirror point of the flash seen from
    # the camera, halfway between them; the camera is held 0.03-0.3 half-widths off the axis.
    from svbrdf_train.data.stats import highlight_position

    n = 96
    flat = SVBRDF(
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, n, n).contiguous(),
        torch.full((1, 3, n, n), 0.02),
        torch.full((1, 1, n, n), 0.25),
        torch.full((1, 3, n, n), 0.5),
    )
    for i in range(6):
        scene = photo_scene(0, i)
        mirror = scene.camera.position[:2] + scene.lights[0].offset[:2] / 2
        found = highlight_position(render(flat, scene))[0]
        assert torch.allclose(found, mirror, atol=0.04), (i, found, mirror)
    shifts = torch.stack([photo_scene(0, i).camera.position[:2].norm() for i in range(200)])
    assert 0.13 < float(shifts.mean()) < 0.2 and float(shifts.min()) >= 0.03 and float(shifts.max()) <= 0.3


def test_dataloader_with_two_workers_gives_the_same_bytes():
    data = ProceduralMaterials(6, 32, seed=3, mix=0.5)
    loader = DataLoader(data, batch_size=3, num_workers=2)
    got = list(loader)
    assert [n for b in got for n in b["name"]] == [f"procedural:3:{i}" for i in range(6)]
    maps = torch.cat([b["maps"] for b in got])
    photos = torch.cat([b["input"] for b in got])
    direct = data.batch(range(6))
    assert torch.equal(maps, direct["maps"]) and torch.equal(photos, direct["input"])


def test_families_and_mix_restrict_the_draw():
    data = ProceduralMaterials(20, 16, seed=0, families=["wood", "metal"], mix=0.0)
    assert {data.family(i) for i in range(20)} == {"wood", "metal"}
    assert all("+" not in data.family(i) for i in range(20))


def test_bad_arguments_are_clear_errors():
    with pytest.raises(DataError, match="unknown material family 'rubber'.*stone, tiles"):
        ProceduralMaterials(4, families=["rubber"])
    with pytest.raises(DataError, match="unknown material family 'glass'"):
        material(0, 0, 16, family="stone+glass")
    with pytest.raises(DataError, match="mix"):
        ProceduralMaterials(4, mix=1.5)
    with pytest.raises(DataError, match="resolution"):
        ProceduralMaterials(4, resolution=1)
    with pytest.raises(DataError, match="count"):
        ProceduralMaterials(-1)
    with pytest.raises(IndexError):
        ProceduralMaterials(4, 16)[4]
    with pytest.raises(DataError, match="exposure_ev"):
        PhotoSettings(exposure_ev=(1.0, -1.0))
    with pytest.raises(DataError, match="camera_shift"):
        PhotoSettings(camera_shift=(0.3, 0.1))
    with pytest.raises(DataError, match="camera_shift"):
        PhotoSettings(camera_shift=(-0.1, 0.1))
