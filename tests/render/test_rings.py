"""The flash's ring in maps (svbrdf_render.refinement.rings): where the flash was, taking a ring out of
maps without touching their texture, the ring penalty on every map of a refinement, and the
dielectric prior on specular."""

from __future__ import annotations

import pytest
import torch

from svbrdf_render import SVBRDF, Scene, refine_maps, render
from svbrdf_render.errors import MapError
from svbrdf_render.geometry import surface_positions
from svbrdf_render.refinement.fit import axis_flash
from svbrdf_render.refinement.refine import DIELECTRIC_F0, RefineSettings, dielectric_prior
from svbrdf_render.refinement.rings import RingBins, dering, highlight_point, ring_penalty

SIZE = 64
CENTRE = torch.tensor([[0.25, -0.375]])


def _radius(point: torch.Tensor = CENTRE, size: int = SIZE) -> torch.Tensor:
    p = surface_positions(size, size)[:2]
    return (p - point[0].view(2, 1, 1)).norm(dim=0)


def _texture(seed: int, size: int = SIZE) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return 0.3 + 0.2 * torch.rand(1, 3, size, size, generator=g)


def _ring_spread(x: torch.Tensor, point: torch.Tensor = CENTRE) -> float:
    return float(RingBins(point, x.shape).spread(x))


def _bump_normals(point: torch.Tensor, height: float) -> torch.Tensor:
    """Normals of a Gaussian bump centred on ``point`` (a relief stamped around the flash)."""
    p = surface_positions(SIZE, SIZE)[:2]
    d = p - point[0].view(2, 1, 1)
    h = height * torch.exp(-(d.square().sum(0)) / 0.1)
    gx = -2 * d[0] / 0.1 * h
    gy = -2 * d[1] / 0.1 * h
    n = torch.stack([-gx, -gy, torch.ones_like(gx)])
    return (n / n.norm(dim=0, keepdim=True))[None]


def test_the_highlight_is_found_where_the_flash_was():
    """A photo of a uniform shiny material under a light moved off the axis: the highlight
    (and so the point) follows the light; row 0 is the top (y = +1), as the renderer's."""
    maps = SVBRDF.constant(1, SIZE, diffuse=(0.2,) * 3, roughness=0.2, specular=(0.5,) * 3)
    for x, y in ((0.0, 0.0), (0.4, -0.3), (-0.5, 0.5)):
        scene = Scene.from_dict(
            {"camera": {"position": [0, 0, 2.2]}, "lights": [{"type": "point", "position": [x, y, 2.2],
             "intensity": 15.0}]}
        )  # fmt: skip
        photo = render(maps, scene).clamp(0, 1)
        found = highlight_point(photo)[0]
        # The mirror direction between camera and light puts the highlight half way between.
        assert found.tolist() == pytest.approx([x / 2, y / 2], abs=0.08)


def test_a_photo_without_a_clear_highlight_gets_the_centre():
    """A rough, strongly textured material: its brightest blurred point is texture, not the
    flash; the point is the centre. The same texture with a highlight stamped off-centre
    (the control) gets the highlight's position."""
    photo = _texture(2).expand(1, 3, SIZE, SIZE).contiguous()
    assert highlight_point(photo)[0].tolist() == [0.0, 0.0]
    spot = torch.exp(-(_radius() / 0.15) ** 2)[None, None]
    lit = (photo + 2.0 * spot).clamp(0, 1)
    assert highlight_point(lit)[0].tolist() == pytest.approx(CENTRE[0].tolist(), abs=0.08)


def test_axis_flash_over_a_point_stands_over_it():
    """Camera and flash over a given point; its intensity is still the one that explains the
    photo: the true one for the true maps."""
    maps = SVBRDF.constant(1, SIZE, diffuse=(0.3,) * 3, roughness=0.4, specular=(0.04,) * 3)
    over = torch.tensor([[0.3, -0.2]])
    scene = axis_flash(SVBRDF.constant(1, SIZE), torch.zeros(1, 3, SIZE, SIZE), over=over)
    assert scene.lights[0].position.reshape(-1).tolist() == pytest.approx([0.3, -0.2, 2.2])
    truth = Scene.from_dict({"camera": {"position": [0.3, -0.2, 2.2]},
                             "lights": [{"type": "point", "position": [0.3, -0.2, 2.2], "intensity": 12.0}]})  # fmt: skip
    photo = render(maps, truth).clamp(0, 1)
    found = axis_flash(maps, photo, over=over)
    assert float(torch.as_tensor(found.lights[0].intensity)) == pytest.approx(12.0, rel=1e-3)


def test_dering_takes_a_disc_out_and_keeps_the_texture():
    """A textured diffuse with a bright disc stamped around the flash: after dering its ring
    spread is that of the texture alone, and the texture inside each ring is kept. The control:
    the stamped map's ring spread is many times larger."""
    texture = _texture(0)
    disc = 1 + 0.8 * torch.exp(-(_radius() / 0.4) ** 2)
    stamped = (texture * disc).clamp(0, 1)
    maps = SVBRDF(torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, SIZE, SIZE), stamped,
                  texture[:, :1], stamped * 0.1)  # fmt: skip
    out = dering(maps, CENTRE)
    assert _ring_spread(stamped) > 8 * _ring_spread(texture)
    # What is left is the disc's shape inside a ring (the profile is read linearly between
    # ring centres): a few percent of the stamp.
    assert _ring_spread(out.diffuse) < 0.1 * _ring_spread(stamped)
    assert _ring_spread(out.specular) < 0.1 * _ring_spread(stamped * 0.1)
    # Texture kept: the dered map correlates with the texture as well as the stamp did not.
    corr = torch.corrcoef(torch.stack([out.diffuse.flatten(), texture.flatten()]))[0, 1]
    assert float(corr) > 0.9


def test_dering_leaves_a_map_without_rings_nearly_alone():
    texture = _texture(1)
    maps = SVBRDF(torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, SIZE, SIZE), texture,
                  texture[:, :1], texture * 0.2)  # fmt: skip
    out = dering(maps, CENTRE)
    assert float((out.diffuse - texture).abs().max()) < 0.05
    assert float((out.roughness - texture[:, :1]).abs().max()) < 0.05


def test_dering_flattens_a_bump_around_the_flash_but_keeps_a_tilt():
    """A bump centred on the flash has a radial slope in every ring; dering removes it. A
    uniform tilt has none (its radial slope averages to 0 over a whole ring), so it stays."""
    flat = SVBRDF.constant(1, SIZE)
    bumped = SVBRDF(_bump_normals(CENTRE, 0.3), flat.diffuse, flat.roughness, flat.specular)
    bins = RingBins(CENTRE, bumped.normal.shape)
    before = bins.spread(bins.radial_slope(bumped.normal)) + bins.radial_slope(bumped.normal).abs().mean()
    out = dering(bumped, CENTRE)
    after = bins.radial_slope(out.normal).abs().mean()
    assert float(after) < 0.1 * float(before)
    tilt = torch.tensor([0.2, 0.1, 1.0])
    tilted = SVBRDF((tilt / tilt.norm()).view(1, 3, 1, 1).expand(1, 3, SIZE, SIZE), flat.diffuse,
                    flat.roughness, flat.specular)  # fmt: skip
    point = torch.zeros(1, 2)  # centred: every ring is whole, so the tilt cancels in each
    assert torch.allclose(dering(tilted, point).normal, tilted.normal, atol=0.02)


def test_the_ring_penalty_sees_every_map():
    base = SVBRDF.constant(1, SIZE, diffuse=(0.3,) * 3, roughness=0.4, specular=(0.05,) * 3)
    bins = RingBins(CENTRE, (1, 3, SIZE, SIZE))
    assert float(ring_penalty(base, bins)) < 1e-5
    disc = torch.exp(-(_radius() / 0.4) ** 2)[None, None]
    for name in ("diffuse", "roughness", "specular"):
        maps = dict(base.maps())
        maps[name] = (maps[name] * (1 + disc)).clamp(0, 1)
        assert float(ring_penalty(SVBRDF(**maps), bins)) > 0.01, name
    bumped = SVBRDF(_bump_normals(CENTRE, 0.3), base.diffuse, base.roughness, base.specular)
    assert float(ring_penalty(bumped, bins)) > 0.01


def test_refinement_takes_a_roughness_ring_out():
    """A uniform material photographed; the start's roughness carries a ring around the flash.
    With the ring penalty the refined roughness loses most of it; without (``rings=0``, the
    control) it keeps more."""
    truth = SVBRDF.constant(1, SIZE, diffuse=(0.3,) * 3, roughness=0.35, specular=(0.04,) * 3)
    scene = Scene.flash(intensity=15.0)
    photo = render(truth, scene).clamp(0, 1)
    centre = torch.zeros(1, 2)
    ring = torch.exp(-(_radius(centre) / 0.35) ** 2)[None, None]
    start = SVBRDF(truth.normal, truth.diffuse, (truth.roughness + 0.3 * ring).clamp(0, 1), truth.specular)
    kept = refine_maps(photo, start, scene=scene, steps=80, backend="eager", settings=RefineSettings(rings=0.0))
    out = refine_maps(photo, start, scene=scene, steps=80, backend="eager", highlight=centre)
    spread = lambda m: _ring_spread(m.roughness, centre)  # noqa: E731
    assert spread(out.svbrdf) < 0.6 * spread(kept.svbrdf)


def test_a_dielectric_start_gets_the_grey_specular_prior_and_a_metal_keeps_its_own():
    dull = SVBRDF.constant(2, 8, specular=(0.07,) * 3)
    metal = SVBRDF.constant(1, 8, specular=(0.9, 0.7, 0.3))
    both = SVBRDF(*(torch.cat([a, b]) for a, b in zip(dull.maps().values(), metal.maps().values(), strict=True)))
    prior = dielectric_prior(both, 0.1)
    assert torch.allclose(prior.specular[:2], torch.full_like(prior.specular[:2], DIELECTRIC_F0))
    assert torch.equal(prior.specular[2:], both.specular[2:])
    assert dielectric_prior(both, 0.0) is both


def test_the_dielectric_prior_moves_a_dull_specular_toward_its_physical_value():
    """The photo of a dielectric at 0.04, a start that says 0.08: with the prior the refined
    specular ends nearer 0.04 than without (``dielectric=0``, the control)."""
    truth = SVBRDF.constant(1, 32, diffuse=(0.2,) * 3, roughness=0.3, specular=(0.04,) * 3)
    scene = Scene.flash(intensity=15.0)
    photo = render(truth, scene).clamp(0, 1)
    start = SVBRDF(truth.normal, truth.diffuse, truth.roughness, torch.full_like(truth.specular, 0.08))
    free = refine_maps(photo, start, scene=scene, steps=60, backend="eager", settings=RefineSettings(dielectric=0))
    held = refine_maps(photo, start, scene=scene, steps=60, backend="eager")
    err = lambda m: float((m.specular - 0.04).abs().mean())  # noqa: E731
    assert err(held.svbrdf) < 0.7 * err(free.svbrdf)


@pytest.mark.parametrize("size", [1, 2, 16])
def test_rings_and_dering_are_finite_forward_and_backward_on_hard_maps(size):
    """Maps at 0 and 1, grazing normals, a 1x1 patch, a point outside the patch."""
    n = torch.zeros(1, 3, size, size)
    n[:, 0] = 1.0  # grazing
    maps = SVBRDF(n, torch.zeros(1, 3, size, size), torch.ones(1, 1, size, size), torch.zeros(1, 3, size, size),
                  validate=False)  # fmt: skip
    for point in (torch.zeros(1, 2), torch.tensor([[3.0, -3.0]])):
        out = dering(maps, point)
        for name, t in out.maps().items():
            assert bool(torch.isfinite(t).all()), name
        d = torch.full((1, 3, size, size), 0.5, requires_grad=True)
        r = torch.full((1, 1, size, size), 0.5, requires_grad=True)
        loss = ring_penalty(SVBRDF(n, d, r, d, validate=False), RingBins(point, (1, 3, size, size)))
        loss.backward()
        assert bool(torch.isfinite(loss)) and bool(torch.isfinite(d.grad).all()) and bool(torch.isfinite(r.grad).all())


@pytest.mark.parametrize(
    ("point", "match"),
    [(torch.zeros(3), "highlight must be"), (torch.zeros(2, 2, 2), "highlight must be"), ([0.0, 0.0], "highlight"),
     (torch.tensor([float("nan"), 0.0]), "non-finite")],
)  # fmt: skip
def test_a_bad_highlight_is_refused(point, match):
    with pytest.raises(MapError, match=match):
        refine_maps(torch.zeros(1, 3, 8, 8), SVBRDF.constant(1, 8), steps=1, highlight=point)


def test_a_bad_dielectric_setting_is_refused():
    with pytest.raises(ValueError, match="dielectric"):
        RefineSettings(dielectric=1.5)


def _full_size_blur_point(photo: torch.Tensor) -> torch.Tensor:
    """``(B, 2)``: the brightest point of ``photo`` after the box blur an eighth of its width wide
    at full size (what :func:`highlight_point` searched before issue 47: ``avg_pool2d`` at
    stride 1, padding not counted), computed exactly from an integral image, so cheaply."""
    b, _, h, w = photo.shape
    y = photo.double().mean(1)
    r = (max(3, round(w / 8)) | 1) // 2
    s = torch.nn.functional.pad(y.cumsum(1).cumsum(2), (1, 0, 1, 0))
    i0, i1 = (torch.arange(h) - r).clamp(0, h), (torch.arange(h) + r + 1).clamp(0, h)
    j0, j1 = (torch.arange(w) - r).clamp(0, w), (torch.arange(w) + r + 1).clamp(0, w)
    total = s[:, i1][:, :, j1] - s[:, i0][:, :, j1] - s[:, i1][:, :, j0] + s[:, i0][:, :, j0]
    i = (total / ((i1 - i0)[:, None] * (j1 - j0)[None])).flatten(1).argmax(1)
    rows, cols = (i // w).double(), (i % w).double()
    return torch.stack([2 * (cols + 0.5) / w - 1, 1 - 2 * (rows + 0.5) / h], 1).float()


def _spot_photo(h: int, w: int, point: tuple[float, float], seed: int = 0) -> torch.Tensor:
    """A textured photo with a soft highlight at ``point`` (patch coordinates)."""
    p = surface_positions(h, w)[:2]
    spot = torch.exp(-((p - torch.tensor(point).view(2, 1, 1)).norm(dim=0) / 0.2) ** 2)
    noise = torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(seed))
    return (0.2 + 0.2 * noise + 0.8 * spot).clamp(0, 1)


def test_the_integral_image_blur_is_the_full_size_box_blur():
    photo = _spot_photo(40, 56, (0.3, -0.4), seed=1)
    k = max(3, round(56 / 8)) | 1
    blurred = torch.nn.functional.avg_pool2d(photo.mean(1, keepdim=True), k, stride=1, padding=k // 2,
                                             count_include_pad=False).flatten(1)  # fmt: skip
    i = int(blurred.argmax(1))
    expected = [2 * (i % 56 + 0.5) / 56 - 1, 1 - 2 * (i // 56 + 0.5) / 40]
    assert _full_size_blur_point(photo)[0].tolist() == pytest.approx(expected)


@pytest.mark.parametrize(("h", "w"), [(2048, 2048), (600, 1500), (1500, 600)])
def test_a_large_photo_is_searched_at_a_working_size_where_the_full_size_blur_finds_it(h, w, monkeypatch):
    # issue 47: the blur at full size took 8.3 s at 1024 px and 150 s at 2048 px
    from svbrdf_render.refinement import rings
    from svbrdf_render.refinement.rings import WORK_SIDE, find_highlight

    blurred, pool = [], torch.nn.functional.avg_pool2d
    monkeypatch.setattr(rings.F, "avg_pool2d", lambda y, *a, **k: blurred.append(y.shape) or pool(y, *a, **k))
    photo = _spot_photo(h, w, (0.3, -0.45))
    point, clear = find_highlight(photo)
    assert blurred and max(blurred[0][-2:]) == WORK_SIDE  # the blur's cost does not grow with the photo
    working = 2 * max(h, w) / WORK_SIDE / torch.tensor([w, h])  # one working pixel, in patch units
    assert bool(clear[0])
    assert ((point[0] - _full_size_blur_point(photo)[0]).abs() <= working).all(), point
    assert point[0].tolist() == pytest.approx([0.3, -0.45], abs=0.02)  # where the highlight is


@pytest.mark.parametrize(("h", "w"), [(256, 256), (200, 256), (256, 96), (64, 64)])
def test_a_photo_at_the_working_size_or_under_gets_the_point_it_always_got(h, w):
    photo = _spot_photo(h, w, (-0.2, 0.35), seed=2)
    ignore = torch.zeros(1, 1, h, w, dtype=torch.bool)
    ignore[..., : h // 4, : w // 4] = True
    for mask in (None, ignore):
        y = photo.mean(1, keepdim=True)
        y = y if mask is None else y.masked_fill(mask, 0.0)
        k = max(3, round(w / 8)) | 1
        blurred = torch.nn.functional.avg_pool2d(y, k, stride=1, padding=k // 2,
                                                 count_include_pad=False).flatten(1)  # fmt: skip
        i = blurred.max(1)[1]
        rows, cols = (i // w).float(), (i % w).float()
        before = torch.stack([2 * (cols + 0.5) / w - 1, 1 - 2 * (rows + 0.5) / h], dim=1)
        assert torch.equal(highlight_point(photo, mask), before)
