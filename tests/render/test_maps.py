"""The SVBRDF container: validation, packing, and transforms that keep normals consistent."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import SVBRDF, MapError, Scene, render


def test_constant_material_has_unit_normals_and_given_values():
    m = SVBRDF.constant(3, (8, 12), diffuse=(0.2, 0.3, 0.4), roughness=0.7, normal=(1, 0, 1))
    assert m.shape == (3, 8, 12)
    assert torch.allclose(m.normal.norm(dim=1), torch.ones(3, 8, 12))
    assert torch.allclose(m.diffuse[0, :, 0, 0], torch.tensor([0.2, 0.3, 0.4]))
    assert float(m.roughness.mean()) == pytest.approx(0.7)


@pytest.mark.parametrize(
    "field, bad, fragment",
    [
        ("normal", torch.zeros(1, 2, 4, 4), "expected shape (B, 3, H, W), got (1, 2, 4, 4)"),
        ("roughness", torch.zeros(1, 3, 4, 4), "map 'roughness': expected shape (B, 1, H, W)"),
        ("diffuse", torch.zeros(1, 3, 5, 4), "differ from the normal map's"),
        ("specular", torch.zeros(1, 3, 4, 4, dtype=torch.int64), "floating-point"),
        ("diffuse", torch.zeros(3, 4, 4), "expected shape (B, 3, H, W), got (3, 4, 4)"),
        ("diffuse", torch.zeros(1, 3, 4, 4, dtype=torch.float64), "float64"),
    ],
)
def test_construction_errors_name_the_map_and_both_shapes(field, bad, fragment):
    maps = dict(SVBRDF.constant(1, 4).maps())
    maps[field] = bad
    with pytest.raises(MapError) as e:
        SVBRDF(**maps)
    assert fragment in str(e.value)


@pytest.mark.parametrize("field", ["diffuse", "roughness", "specular"])
@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan")])
def test_out_of_range_values_are_refused_with_the_range(field, value):
    maps = dict(SVBRDF.constant(1, 4).maps())
    t = maps[field].clone()
    t[0, 0, 1, 2] = value
    maps[field] = t
    with pytest.raises(MapError) as e:
        SVBRDF(**maps)
    assert f"map '{field}'" in str(e.value) and "[0, 1]" in str(e.value)
    SVBRDF(**maps, validate=False)  # the caller may opt out


def test_pack_unpack_round_trip_and_des18_twelve_channels():
    m = random_svbrdf(2, 8)
    packed = m.pack()
    assert packed.shape == (2, 10, 8, 8)
    back = SVBRDF.unpack(packed)
    for name, t in m.maps().items():
        assert torch.equal(getattr(back, name), t)
    twelve = torch.cat([m.normal, m.diffuse, m.roughness.expand(-1, 3, -1, -1), m.specular], 1)
    assert torch.allclose(SVBRDF.unpack(twelve).roughness, m.roughness)
    with pytest.raises(MapError, match=r"\(B, 10, H, W\)"):
        SVBRDF.unpack(torch.zeros(1, 9, 4, 4))


def test_crop_center_crop_and_resize():
    m = random_svbrdf(1, 16)
    c = m.crop(2, 3, 8, 5)
    assert c.size == (8, 5)
    assert torch.equal(c.diffuse, m.diffuse[:, :, 2:10, 3:8])
    assert torch.equal(m.center_crop(8).normal, m.normal[:, :, 4:12, 4:12])
    with pytest.raises(MapError, match="does not fit"):
        m.crop(10, 0, 8)
    r = m.resize(7)
    assert r.size == (7, 7)
    assert torch.allclose(r.normal.norm(dim=1), torch.ones(1, 7, 7), atol=1e-5)
    assert float(r.diffuse.min()) >= 0 and float(r.diffuse.max()) <= 1


def _dihedral():
    return {
        "identity": lambda x: x,
        "flip_h": lambda x: x.flip_horizontal(),
        "flip_v": lambda x: x.flip_vertical(),
        "rot90": lambda x: x.rot90(1),
        "rot180": lambda x: x.rot90(2),
        "rot270": lambda x: x.rot90(3),
        "transpose": lambda x: x.transpose(),
        "anti_transpose": lambda x: x.transpose().rot90(2),
    }


_IMAGE_OPS = {
    "identity": lambda t: t,
    "flip_h": lambda t: t.flip(-1),
    "flip_v": lambda t: t.flip(-2),
    "rot90": lambda t: torch.rot90(t, 1, (-2, -1)),
    "rot180": lambda t: torch.rot90(t, 2, (-2, -1)),
    "rot270": lambda t: torch.rot90(t, 3, (-2, -1)),
    "transpose": lambda t: t.transpose(-2, -1),
    "anti_transpose": lambda t: torch.rot90(t.transpose(-2, -1), 2, (-2, -1)),
}


@pytest.mark.parametrize("name", list(_IMAGE_OPS))
def test_transforms_rotate_normals_with_the_image(name):
    # Under an on-axis camera and flash the scene is symmetric, so rendering a transformed
    # material must give the transformed rendering. A transform that moved pixels without
    # rotating the normals would move the highlights the wrong way and fail this.
    m = random_svbrdf(2, 12, seed=3, tilt=0.8)
    scene = Scene.flash(distance=1.5, intensity=5.0)
    expected = _IMAGE_OPS[name](render(m, scene))
    got = render(_dihedral()[name](m), scene)
    assert torch.allclose(got, expected, rtol=1e-4, atol=1e-6)
    if name != "identity":  # the check has teeth: moving pixels alone is not enough
        moved = _IMAGE_OPS[name]
        naive = SVBRDF(*(moved(t) for t in m.maps().values()))
        assert not torch.allclose(render(naive, scene), expected, rtol=1e-3, atol=1e-4)


def test_rotations_compose_to_identity():
    m = random_svbrdf(1, 6)
    for t in (m.rot90(4), m.rot90(1).rot90(3), m.flip_horizontal().flip_horizontal()):
        for name, a in m.maps().items():
            assert torch.allclose(getattr(t, name), a)


def test_batch_indexing_and_cat():
    m = random_svbrdf(3, 4)
    assert m[1].batch_size == 1 and torch.equal(m[1].diffuse, m.diffuse[1:2])
    assert SVBRDF.cat([m[0], m[2]]).batch_size == 2
    assert m.to(torch.float64).dtype == torch.float64
