"""des18 maps <-> glTF metal/rough maps: the exact direction, the named cases, hard cases, errors.

Tolerances of the exact direction (metal/rough -> des18 -> metal/rough):
- float32, 2e-6: the metallic root depends on ``Ys - 0.04``, whose float32 rounding (~4e-9 near
  0.04) is divided by ``Y(b) - 0.04`` (at least 0.02 on the maps drawn here), so ``m`` moves by
  ~2e-7 at most and ``b`` (``|db/dm| <= 1.04``) by as much; 2e-6 leaves a margin of ten.
- float64, 1e-12: the same argument with 1e-17 rounding.
The maps drawn for it avoid the two regions the module doc names as not exact: a metallic base
colour of luminance at most 0.04, and ``m`` below ``DIELECTRIC_TOLERANCE / (Y(b) - 0.04)``
(5e-5 here), which counts as a dielectric.
"""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import (
    SVBRDF,
    MapError,
    MetalRough,
    Scene,
    evaluation_scene,
    from_metal_rough,
    roundtrip_error,
    to_metal_rough,
)
from svbrdf_render.metalrough import LUMINANCE

#: |dm/dYs| <= 5e3 on every metallic pixel (module doc: the dielectric tolerance keeps the
#: discriminant >= 0.16e-6); |db/dm| <= 2.1, and a summed loss adds 3 channels and the round
#: trip's maps: 1e5 bounds it with a margin, and is far below what a NaN-guard failure gives.
GRAD_BOUND = 1e5
#: The bound on |dm/dYs| itself: 5 / sqrt(DIELECTRIC_TOLERANCE).
DM_DYS_BOUND = 5e3


def _lum(rgb: torch.Tensor) -> torch.Tensor:
    w = torch.tensor(LUMINANCE, dtype=rgb.dtype).view(1, 3, 1, 1)
    return (rgb * w).sum(1, keepdim=True)


def _flat_normal(b: int, h: int, w: int, dtype=torch.float32) -> torch.Tensor:
    n = torch.zeros(b, 3, h, w, dtype=dtype)
    n[:, 2] = 1
    return n


def _random_metal_rough(dtype=torch.float32, size: int = 24, seed: int = 0) -> MetalRough:
    """Batch 0 dielectric, 1 pure metal, 2 in between, 3 a per-pixel mix of the three."""
    g = torch.Generator().manual_seed(seed)
    b = torch.rand(4, 3, size, size, generator=g, dtype=dtype)
    m = 1e-3 + (1 - 1e-3) * torch.rand(4, 1, size, size, generator=g, dtype=dtype)
    m[0], m[1] = 0, 1
    pick = torch.randint(0, 3, (1, 1, size, size), generator=g)
    m[3:] = torch.where(pick == 0, 0.0, torch.where(pick == 1, 1.0, m[3:])).to(dtype)
    # metals darker than 0.06 in luminance are brightened (1 - b): the exact region (module doc)
    dark = (_lum(b) < 0.06) & (m > 0)
    b = torch.where(dark, 1 - b, b)
    r = torch.rand(4, 1, size, size, generator=g, dtype=dtype)
    n = torch.nn.functional.normalize(
        torch.randn(4, 3, size, size, generator=g, dtype=dtype) * 0.3 + torch.tensor([0, 0, 1], dtype=dtype).view(1, 3, 1, 1),
        dim=1,
    )
    return MetalRough(b, m, r, n)


# -- the exact direction ---------------------------------------------------------------------------


@pytest.mark.parametrize("dtype, tol", [(torch.float32, 2e-6), (torch.float64, 1e-12)])
def test_metal_rough_comes_back_from_des18(dtype, tol):
    mr = _random_metal_rough(dtype)
    assert bool((_lum(mr.basecolor)[mr.metallic[:, :1] > 0] > 0.06).all())
    back = to_metal_rough(from_metal_rough(mr))
    assert back.basecolor.dtype == dtype and back.metallic.dtype == dtype
    torch.testing.assert_close(back.metallic, mr.metallic, atol=tol, rtol=0)
    torch.testing.assert_close(back.basecolor, mr.basecolor, atol=tol, rtol=0)
    assert back.roughness is mr.roughness and back.normal is mr.normal


def test_des18_maps_of_a_metal_rough_material_follow_the_gltf_equations():
    b = torch.tensor([0.9, 0.5, 0.2]).view(1, 3, 1, 1).expand(1, 3, 1, 3).clone()
    m = torch.tensor([0.0, 0.5, 1.0]).view(1, 1, 1, 3)
    x = from_metal_rough(MetalRough(b, m, torch.full((1, 1, 1, 3), 0.4), _flat_normal(1, 1, 3)))
    # dielectric: d = b, s = 0.04; half: d = b/2, s = 0.02 + b/2; metal: d = 0, s = b
    torch.testing.assert_close(x.diffuse[0, :, 0, 0], b[0, :, 0, 0])
    torch.testing.assert_close(x.specular[0, :, 0, 0], torch.full((3,), 0.04))
    torch.testing.assert_close(x.diffuse[0, :, 0, 1], b[0, :, 0, 1] / 2)
    torch.testing.assert_close(x.specular[0, :, 0, 1], 0.02 + b[0, :, 0, 1] / 2)
    torch.testing.assert_close(x.diffuse[0, :, 0, 2], torch.zeros(3))
    torch.testing.assert_close(x.specular[0, :, 0, 2], b[0, :, 0, 2])


# -- the named cases -------------------------------------------------------------------------------


def test_a_grey_004_specular_is_a_dielectric_whatever_its_diffuse():
    g = torch.Generator().manual_seed(3)
    d = torch.rand(2, 3, 8, 8, generator=g)
    d[0, :, :2] = 0  # black dielectrics too: d = 0, s = 0.04 is also a metal of base 0.04
    x = SVBRDF(_flat_normal(2, 8, 8), d, torch.full((2, 1, 8, 8), 0.5), torch.full((2, 3, 8, 8), 0.04))
    mr = to_metal_rough(x)
    assert bool((mr.metallic == 0).all())
    torch.testing.assert_close(mr.basecolor, d, atol=0, rtol=0)
    back = from_metal_rough(mr)
    torch.testing.assert_close(back.diffuse, d, atol=0, rtol=0)
    torch.testing.assert_close(back.specular, x.specular, atol=1e-7, rtol=0)


def test_a_pure_metal_has_metallic_1_and_its_specular_as_base_colour():
    g = torch.Generator().manual_seed(4)
    s = 0.1 + 0.9 * torch.rand(2, 3, 8, 8, generator=g)  # luminance above 0.04: a metal's F0
    s[1, :, 0, 0] = 1.0
    s[1, :, 0, 1] = torch.tensor([1.0, 0.78, 0.34])  # gold
    x = SVBRDF(_flat_normal(2, 8, 8), torch.zeros_like(s), torch.full((2, 1, 8, 8), 0.3), s)
    mr = to_metal_rough(x)
    torch.testing.assert_close(mr.metallic, torch.ones_like(mr.metallic), atol=1e-6, rtol=0)
    torch.testing.assert_close(mr.basecolor, s, atol=1e-6, rtol=0)


def test_grey_des18_maps_the_metal_rough_model_can_hold_come_back_exactly():
    # grey d, s with s >= 0.04 and d + s <= 1: one (b, m) reproduces them (module doc)
    g = torch.Generator().manual_seed(5)
    s = 0.04 + 0.6 * torch.rand(1, 1, 32, 32, generator=g)
    d = (1 - s) * torch.rand(1, 1, 32, 32, generator=g)
    x = SVBRDF(_flat_normal(1, 32, 32), d.expand(1, 3, 32, 32), torch.full_like(d, 0.5), s.expand(1, 3, 32, 32))
    back = from_metal_rough(to_metal_rough(x))
    torch.testing.assert_close(back.diffuse, x.diffuse, atol=2e-6, rtol=0)
    torch.testing.assert_close(back.specular, x.specular, atol=2e-6, rtol=0)


def test_coloured_maps_keep_their_luminances_when_nothing_is_clamped():
    # d in [0, 0.3], s in [0.04, 0.3]: b = (1 + m) d + m s - 0.04 m (1 - m) stays in [0, 0.9]
    g = torch.Generator().manual_seed(6)
    d = 0.3 * torch.rand(2, 3, 16, 16, generator=g)
    s = 0.04 + 0.26 * torch.rand(2, 3, 16, 16, generator=g)
    x = SVBRDF(_flat_normal(2, 16, 16), d, torch.full((2, 1, 16, 16), 0.5), s)
    back = from_metal_rough(to_metal_rough(x))
    torch.testing.assert_close(_lum(back.diffuse), _lum(d), atol=2e-6, rtol=0)
    torch.testing.assert_close(_lum(back.specular), _lum(s), atol=2e-6, rtol=0)
    # ...but not the colours: one base colour cannot carry a diffuse tint and a specular tint
    assert float((back.specular - s).abs().max()) > 0.01


def test_specular_below_the_dielectric_floor_comes_back_at_004():
    d = torch.full((1, 3, 4, 4), 0.5)
    s = torch.full((1, 3, 4, 4), 0.02)
    s[..., 0, 0] = 0.0
    back = from_metal_rough(to_metal_rough(SVBRDF(_flat_normal(1, 4, 4), d, torch.full((1, 1, 4, 4), 0.5), s)))
    torch.testing.assert_close(back.specular, torch.full_like(s, 0.04))
    torch.testing.assert_close(back.diffuse, d)


def test_a_metal_darker_than_a_dielectric_comes_back_as_a_dielectric():
    mr = MetalRough(torch.full((1, 3, 2, 2), 0.02), torch.full((1, 1, 2, 2), 0.5), torch.full((1, 1, 2, 2), 0.5), _flat_normal(1, 2, 2))
    back = to_metal_rough(from_metal_rough(mr))
    assert bool((back.metallic == 0).all())


# -- numerical hard cases --------------------------------------------------------------------------

HARD_VALUES = [0.0, 1e-7, 0.04 - 1e-7, 0.04, 0.04 + 1e-7, 0.04 + 2e-6, 0.08, 0.5, 1 - 1e-7, 1.0]


def _hard_des18(dtype) -> SVBRDF:
    """Every pair of grey (d, s) from HARD_VALUES, and coloured extremes (one channel 0 or 1)."""
    v = torch.tensor(HARD_VALUES, dtype=dtype)
    dd, ss = torch.meshgrid(v, v, indexing="ij")
    grey_d = dd.reshape(1, 1, 1, -1).expand(1, 3, 1, -1)
    grey_s = ss.reshape(1, 1, 1, -1).expand(1, 3, 1, -1)
    eye = torch.eye(3, dtype=dtype).reshape(1, 3, 1, 3)  # pure red, green, blue
    coloured_d = torch.cat([eye, 1 - eye, eye, torch.zeros_like(eye)], dim=3)
    coloured_s = torch.cat([eye, eye, torch.zeros_like(eye), 1 - eye], dim=3)
    d = torch.cat([grey_d, coloured_d], dim=3).contiguous()
    s = torch.cat([grey_s, coloured_s], dim=3).contiguous()
    n = d.shape[3]
    return SVBRDF(_flat_normal(1, 1, n, dtype), d, torch.full((1, 1, 1, n), 0.5, dtype=dtype), s)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_hard_des18_maps_convert_finite_and_bounded_forward_and_backward(dtype):
    x = _hard_des18(dtype)
    d = x.diffuse.clone().requires_grad_(True)
    s = x.specular.clone().requires_grad_(True)
    mr = to_metal_rough(SVBRDF(x.normal, d, x.roughness, s))
    for name in ("basecolor", "metallic"):
        t = getattr(mr, name).detach()
        assert torch.isfinite(t).all() and float(t.min()) >= 0 and float(t.max()) <= 1, name
    back = from_metal_rough(mr)
    loss = mr.basecolor.sum() + mr.metallic.sum() + back.diffuse.sum() + back.specular.sum()
    loss.backward()
    for name, t in (("diffuse", d), ("specular", s)):
        assert torch.isfinite(t.grad).all(), f"non-finite gradient for {name}"
        assert float(t.grad.abs().max()) <= GRAD_BOUND, name


def test_the_branch_point_is_reached_and_stays_bounded():
    # Yd = Ys = 0.04: the exact dm/dYs grows as 1/sqrt(Ys - 0.04); the dielectric tolerance
    # stops it at 5e3. Approached from both sides of B = Yd + Ys - 0.08 = 0.
    eps = torch.tensor([1e-7, 1e-6, 1.2e-6, 2e-6, 1e-5, 1e-4]).repeat(3)
    n = eps.numel()
    ys = (0.04 + eps).view(1, 1, 1, n)
    s = ys.expand(1, 3, 1, n).clone().requires_grad_(True)
    yd = 0.08 - ys + torch.tensor([0.0, 1e-4, -1e-4]).repeat_interleave(6).view(1, 1, 1, n)
    x = SVBRDF(_flat_normal(1, 1, n), yd.expand(1, 3, 1, n).contiguous(), torch.full((1, 1, 1, n), 0.5), s)
    m = to_metal_rough(x).metallic
    (grad,) = torch.autograd.grad(m.sum(), s)  # dm/ds_c = w_c dm/dYs: their sum is dm/dYs
    assert torch.isfinite(grad).all()
    assert float(grad.sum(1).abs().max()) <= DM_DYS_BOUND
    assert float(grad.sum(1).abs().max()) > DM_DYS_BOUND / 10  # the steep region is reached
    assert float(m.detach().max()) < 0.2  # continuous: a tiny excess specular gives a small metallic


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_hard_metal_rough_maps_convert_finite_and_bounded_forward_and_backward(dtype):
    v = torch.tensor([0.0, 1e-7, 0.5, 1 - 1e-7, 1.0], dtype=dtype)
    bb, mm = torch.meshgrid(v, v, indexing="ij")
    n = bb.numel()
    b = bb.reshape(1, 1, 1, n).expand(1, 3, 1, n).clone().requires_grad_(True)
    m = mm.reshape(1, 1, 1, n).clone().requires_grad_(True)
    mr = MetalRough(b, m, torch.full((1, 1, 1, n), 0.5, dtype=dtype), _flat_normal(1, 1, n, dtype))
    x = from_metal_rough(mr)
    again = to_metal_rough(x)
    for t in (x.diffuse, x.specular, again.basecolor, again.metallic):
        t = t.detach()
        assert torch.isfinite(t).all() and float(t.min()) >= 0 and float(t.max()) <= 1
    (x.diffuse.sum() + x.specular.sum() + again.basecolor.sum() + again.metallic.sum()).backward()
    for name, t in (("basecolor", b), ("metallic", m)):
        assert torch.isfinite(t.grad).all(), f"non-finite gradient for {name}"
        assert float(t.grad.abs().max()) <= GRAD_BOUND, name


def test_half_precision_is_converted_in_float32_and_returned_in_half():
    x = random_svbrdf(1, 8).to(torch.float16)
    mr = to_metal_rough(x)
    assert mr.basecolor.dtype == torch.float16 and mr.metallic.dtype == torch.float16
    ref = to_metal_rough(x.to(torch.float32))
    torch.testing.assert_close(mr.basecolor.float(), ref.basecolor, atol=1e-3, rtol=0)
    assert from_metal_rough(mr).specular.dtype == torch.float16


# -- shapes and batches ----------------------------------------------------------------------------


def test_shapes_batches_and_dtypes_are_kept_and_materials_do_not_mix():
    x = random_svbrdf(3, 8, dtype=torch.float64)
    x = SVBRDF(*(t[..., :5] for t in x.maps().values()))  # 8x5: not square
    mr = to_metal_rough(x)
    assert mr.basecolor.shape == (3, 3, 8, 5) and mr.metallic.shape == (3, 1, 8, 5)
    assert mr.roughness is x.roughness and mr.normal is x.normal
    assert mr.shape == (3, 8, 5) and mr.basecolor.dtype == torch.float64
    back = from_metal_rough(mr)
    assert back.shape == x.shape and back.dtype == torch.float64
    one = to_metal_rough(x[1])
    torch.testing.assert_close(one.basecolor, mr.basecolor[1:2], atol=0, rtol=0)
    torch.testing.assert_close(one.metallic, mr.metallic[1:2], atol=0, rtol=0)


# -- bad input -------------------------------------------------------------------------------------


def _mr_parts(size: int = 4) -> dict:
    return {
        "basecolor": torch.rand(2, 3, size, size),
        "metallic": torch.rand(2, 1, size, size),
        "roughness": torch.rand(2, 1, size, size),
        "normal": _flat_normal(2, size, size),
    }


@pytest.mark.parametrize(
    "name, bad",
    [
        ("basecolor", torch.rand(2, 1, 4, 4)),
        ("basecolor", torch.rand(2, 4, 4, 4)),
        ("metallic", torch.rand(2, 3, 4, 4)),
        ("roughness", torch.rand(2, 3, 4, 4)),
        ("normal", torch.rand(2, 2, 4, 4)),
        ("metallic", torch.rand(2, 1, 4, 5)),
        ("metallic", torch.rand(2, 4, 4)),
    ],
)
def test_wrong_channels_or_sizes_are_refused_naming_the_map(name, bad):
    parts = _mr_parts()
    parts[name] = bad
    with pytest.raises(MapError, match=f"'{name}'"):
        MetalRough(**parts)


def test_out_of_range_metal_rough_values_are_refused():
    parts = _mr_parts()
    parts["basecolor"] = parts["basecolor"] * 2 + 0.1
    with pytest.raises(MapError, match="basecolor.*\\[0, 1\\]"):
        MetalRough(**parts)


def test_the_converters_refuse_the_wrong_container():
    with pytest.raises(MapError, match="to_metal_rough: expected an SVBRDF"):
        to_metal_rough(MetalRough(**_mr_parts()))
    with pytest.raises(MapError, match="from_metal_rough: expected MetalRough"):
        from_metal_rough(random_svbrdf(1, 4))
    with pytest.raises(MapError, match="roundtrip_error"):
        roundtrip_error(torch.rand(1, 10, 4, 4))


# -- the round-trip error --------------------------------------------------------------------------


def test_roundtrip_error_is_zero_on_metal_rough_materials_and_not_on_coloured_specular():
    exact = from_metal_rough(_random_metal_rough(size=16))
    err = roundtrip_error(exact)
    assert set(err) == {"normal", "diffuse", "roughness", "specular", "render"}
    for name, v in err.items():
        assert v.shape == (4,) and torch.isfinite(v).all(), name
        assert float(v.max()) < 1e-5, name
    tinted = SVBRDF.constant(2, 16, diffuse=(0.2, 0.4, 0.6), specular=(0.6, 0.1, 0.05))
    err = roundtrip_error(tinted)
    assert float(err["normal"].max()) == 0 and float(err["roughness"].max()) == 0
    assert float(err["specular"].min()) > 0.05 and float(err["render"].min()) > 0.01


def test_roundtrip_error_renders_under_the_scene_it_is_given():
    tinted = SVBRDF.constant(1, 16, diffuse=(0.2, 0.4, 0.6), specular=(0.6, 0.1, 0.05), roughness=0.2)
    under_eval = roundtrip_error(tinted)["render"]
    assert torch.equal(roundtrip_error(tinted, evaluation_scene())["render"], under_eval)
    dark = Scene.flash(intensity=0.0)  # no light: both renderings black
    assert float(roundtrip_error(tinted, dark)["render"][0]) == 0


def test_roundtrip_render_error_is_the_benchmarks_render_rmse():
    from svbrdf_render.compare import map_rmse, render_rmse

    x = random_svbrdf(2, 16, seed=7)
    back = from_metal_rough(to_metal_rough(x))
    torch.testing.assert_close(roundtrip_error(x)["render"], render_rmse(back, x))
    for name, v in map_rmse(back, x).items():
        torch.testing.assert_close(roundtrip_error(x)[name], v)


@pytest.mark.data
def test_unseen_dev_made_from_metal_rough_maps_survives_the_round_trip(shared_data):
    # unseen-dev's maps were made from metal/rough sets with the equations of from_metal_rough.
    # At full size (resizing averages metal and dielectric pixels into pairs no base colour
    # holds), only the files' 8-bit rounding (0.04 is stored as 10/255) and a few metal pixels
    # darker than 0.04 separate them from the exact direction: the renderings must move by less
    # than one 8-bit step, 1/255 = 0.0039.
    from svbrdf_render import read_des18

    files = sorted((shared_data / "unseen-dev").glob("*.png"))
    if not files:
        pytest.skip("unseen-dev has no strips here")
    for f in files:
        err = roundtrip_error(read_des18(f).svbrdf)
        assert float(err["render"][0]) < 0.0039, f.name
