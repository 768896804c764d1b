"""The flash's place read off the fall-off of its light (svbrdf_render.refinement.falloff): found
where it stood on matte, glossy and textured materials, a card's pixels ignored, and bad or empty
photos answered without a crash."""

from __future__ import annotations

import math

import pytest
import torch

from svbrdf_render import SVBRDF, render
from svbrdf_render.refinement.falloff import fall_off_point, tilted_view_factor
from svbrdf_render.refinement.fit import flash_scene
from svbrdf_render.refinement.rings import find_highlight


def _photo(maps: SVBRDF, x: float, y: float, height: float = 2.1) -> torch.Tensor:
    return render(maps, flash_scene(torch.tensor([[x, y, height]]), torch.tensor([12.0]))).clamp(0, 1)


def _textured(size: int = 96, seed: int = 0) -> SVBRDF:
    """Grey with a strong texture at several scales (albedo from 0.1 to 0.5)."""
    g = torch.Generator().manual_seed(seed)
    noise = sum(torch.nn.functional.interpolate(torch.rand(1, 1, k, k, generator=g), size=size, mode="bilinear")
                for k in (4, 12, 48)) / 3  # fmt: skip
    diffuse = (0.1 + 0.4 * noise).expand(1, 3, size, size).clone()
    m = SVBRDF.constant(1, size, roughness=0.5, specular=(0.04,) * 3)
    return SVBRDF(m.normal, diffuse, m.roughness, m.specular)


@pytest.mark.parametrize("roughness", [0.3, 0.5, 0.9])
@pytest.mark.parametrize("at", [(0.45, -0.3), (-0.6, 0.5), (0.0, 0.0)])
def test_the_flash_is_found_where_it_stood_on_a_flat_material(roughness, at):
    maps = SVBRDF.constant(1, 96, diffuse=(0.3,) * 3, roughness=roughness, specular=(0.04,) * 3)
    point, misfit = fall_off_point(_photo(maps, *at), 2.1)
    assert point[0].tolist() == pytest.approx(at, abs=0.04)
    assert 0 <= float(misfit[0]) < 0.05  # a flat material is the model


def test_a_matte_textured_material_without_a_highlight_still_shows_where_the_flash_was():
    """No clear highlight for the highlight finder (texture everywhere, a rough lobe), yet the
    fall-off places the flash within a tenth of a half-width; at the square's centre it stays."""
    photo = _photo(_textured(), 0.5, -0.35)
    _, clear = find_highlight(photo)
    point, misfit = fall_off_point(photo, 2.1)
    assert not bool(clear[0])
    assert point[0].tolist() == pytest.approx([0.5, -0.35], abs=0.1)
    assert 0 < float(misfit[0]) < 0.5
    centred, _ = fall_off_point(_photo(_textured(seed=1), 0.0, 0.0), 2.1)
    assert centred[0].tolist() == pytest.approx([0.0, 0.0], abs=0.1)


def test_a_card_s_pixels_are_ignored_whatever_they_hold():
    """The pixels under ``ignore`` count for nothing: a white card, a black one or NaNs there give
    the same place, the flash's."""
    maps = SVBRDF.constant(1, 96, diffuse=(0.15,) * 3, roughness=0.7, specular=(0.04,) * 3)
    card = torch.zeros(1, 1, 96, 96, dtype=torch.bool)
    card[..., :40, :40] = True
    got = []
    for fill in (1.0, 0.0, float("nan")):
        photo = _photo(maps, 0.3, 0.2)
        photo[..., :40, :40] = fill
        got.append(fall_off_point(photo, 2.1, card))
    assert got[0][0][0].tolist() == pytest.approx([0.3, 0.2], abs=0.05)
    for point, misfit in got[1:]:
        assert torch.equal(point, got[0][0]) and torch.equal(misfit, got[0][1])


def test_the_search_is_centred_where_asked_and_batches_are_independent():
    maps = SVBRDF.constant(2, 64, diffuse=(0.3,) * 3, roughness=0.6, specular=(0.04,) * 3)
    scene = flash_scene(torch.tensor([[0.9, 0.0, 2.0], [-0.2, 0.1, 2.0]]), torch.tensor([12.0, 12.0]))
    photos = render(maps, scene).clamp(0, 1).reshape(2, 3, 64, 64)
    point, _ = fall_off_point(photos, 2.0, around=torch.tensor([[0.8, 0.0], [0.0, 0.0]]), span=0.5)
    assert point.tolist() == [pytest.approx([0.9, 0.0], abs=0.04), pytest.approx([-0.2, 0.1], abs=0.04)]
    near, _ = fall_off_point(photos[:1], 2.0, span=0.5)  # the flash beyond the search: its edge
    assert float(near[0, 0]) <= 0.5 + 0.125 + 1e-6


def test_dark_empty_and_broken_photos_give_the_centre_and_an_infinite_misfit():
    black = torch.zeros(1, 3, 48, 48)
    point, misfit = fall_off_point(black, 2.2, around=torch.tensor([0.1, -0.1]))
    assert point[0].tolist() == pytest.approx([0.1, -0.1]) and misfit[0] == float("inf")
    nan = torch.full((1, 3, 48, 48), float("nan"))
    point, misfit = fall_off_point(nan, 2.2)
    assert torch.isfinite(point).all() and misfit[0] == float("inf")
    covered = torch.ones(1, 1, 48, 48, dtype=torch.bool)
    assert fall_off_point(torch.rand(1, 3, 48, 48), 2.2, covered)[1][0] == float("inf")
    tiny = torch.rand(1, 3, 4, 4) * 0.5 + 0.1  # smaller than the working side: still an answer
    point, misfit = fall_off_point(tiny, 2.2)
    assert torch.isfinite(point).all() and point.abs().max() <= 1.2


@pytest.mark.parametrize(("photo", "height", "match"), [
    (torch.rand(3, 32, 32), 2.0, "photo must be"), (torch.rand(1, 1, 32, 32), 2.0, "photo must be"),
    (torch.rand(1, 3, 32, 32), 0.0, "height must be positive"), (torch.rand(1, 3, 32, 32), float("nan"), "height"),
])  # fmt: skip
def test_bad_arguments_are_refused_in_one_line(photo, height, match):
    with pytest.raises(ValueError, match=match):
        fall_off_point(photo, height)


# --- the perspective of a tilted phone --------------------------------------------------------
def _card(size: int, rows: slice, cols: slice) -> torch.Tensor:
    mask = torch.zeros(1, 1, size, size, dtype=torch.bool)
    mask[..., rows, cols] = True
    return mask


def test_a_tilted_view_meets_the_surface_where_trigonometry_says():
    """A camera tilted by theta about x (standing at -y), aimed at the centre: the ray at angle
    alpha above its axis meets the surface at y = -D sin(theta) + D cos(theta) tan(theta + alpha)."""
    from svbrdf_render.refinement.falloff import _plane_points

    d, theta, focal = 2.2, math.radians(18), 2.2
    camera = torch.tensor([0.0, -d * math.sin(theta), d * math.cos(theta)], dtype=torch.float64)
    v = torch.tensor([-0.9, -0.3, 0.0, 0.4, 0.9], dtype=torch.float64)
    got = _plane_points(camera, focal, torch.zeros_like(v), v)
    want = -d * math.sin(theta) + d * math.cos(theta) * torch.tan(theta + torch.atan(v / focal))
    assert torch.allclose(got[:, 1], want, atol=1e-9) and torch.allclose(got[:, 0], torch.zeros_like(v))


def test_a_card_beyond_a_tilted_phone_s_centre_gets_less_light_than_its_place_says():
    """Phone held at -y, tilted towards the centre: a card at the top of the square (the far side)
    lies farther from the flash than its place in the square, so its reading is too weak (factor
    above 1), more than one at the bottom (under the flash); the phone at +y turns the two
    round; on the axis, no factor (exactly 1)."""
    size, focal = 96, 2.2
    top, bottom = _card(size, slice(4, 20), slice(40, 56)), _card(size, slice(76, 92), slice(40, 56))
    tilted, mirrored = torch.tensor([0.0, -0.7, 2.08]), torch.tensor([0.0, 0.7, 2.08])
    assert tilted_view_factor(top, tilted, focal) > 1.03
    assert tilted_view_factor(bottom, tilted, focal) < tilted_view_factor(top, tilted, focal) - 0.03
    assert tilted_view_factor(bottom, mirrored, focal) == pytest.approx(tilted_view_factor(top, tilted, focal), rel=1e-6)
    axis = torch.tensor([0.0, 0.0, 2.2])
    assert tilted_view_factor(top, axis, focal) == pytest.approx(1.0, abs=1e-9)
    # a tilt along x treats a card at the left as the top one above
    left = _card(size, slice(40, 56), slice(4, 20))
    assert tilted_view_factor(left, torch.tensor([0.7, 0.0, 2.08]), focal) == pytest.approx(
        tilted_view_factor(top, tilted, focal), rel=1e-6)


@pytest.mark.parametrize("camera", [[0.3, 0.2, 0.0], [0.3, 0.2, -2.0], [float("nan"), 0.0, 2.0], [0.0, 0.0, 2.0]])
def test_the_tilt_factor_of_a_broken_pose_or_an_empty_region_is_one(camera):
    mask = _card(32, slice(2, 8), slice(2, 8)) if camera != [0.0, 0.0, 2.0] else torch.zeros(1, 1, 32, 32, dtype=bool)
    assert tilted_view_factor(mask, torch.tensor(camera), 2.0) == 1.0
    assert tilted_view_factor(_card(32, slice(2, 8), slice(2, 8)), torch.tensor([0.0, 0.0, 2.0]), 0.0) == 1.0
