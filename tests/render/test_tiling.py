"""Tileable maps: the seam measure, the half-period cross-fade, and its hard cases.

Bounds used below:
- a map that tiles scores a seam error near 1: its wrap step is one row (column) of steps
  against the average of all. After ``make_tileable`` the wrap pairs are (blends of) the
  original's neighbours at its middle column and row, so the ratio is that of one middle
  column's steps to the whole map's, raised a little by the contrast the blend band loses
  (the maps' std falls by 5-15 % on real maps): below 1.5 for the smooth random textures
  here, where a ramp scores its side minus one;
- gradients: each input pixel reaches at most two output pixels per axis with weights that
  sum to at most 2, so a loss with weights in [-1, 1] gives map gradients of at most 4; the
  normals' renormalisation multiplies that by at most
  1 / |n| <= 1e4 (safe_normalize replaces shorter vectors, with a zero gradient).
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from conftest import random_svbrdf
from svbrdf_render import SVBRDF, MapError
from svbrdf_render.tiling import (
    MIN_TILEABLE_SIDE,
    make_tileable,
    make_tileable_map,
    seam_error,
)


def _texture(b: int, c: int, h: int, w: int, *, seed: int = 0, periodic: bool = False) -> torch.Tensor:
    """Smoothed uniform noise in (0, 1): a stand-in for a uniform material at ~5 px grain.

    ``periodic``: smoothed with wrap-around padding, so opposite edges are neighbours.
    """
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(b, c, h, w, generator=g, dtype=torch.float64)
    x = F.pad(x, (2, 2, 2, 2), mode="circular" if periodic else "replicate")
    x = F.avg_pool2d(x, 5, stride=1)
    return ((x - 0.5) * 2 + 0.5).clamp(0, 1)


def _hard_seam_map(h: int = 96, w: int = 128) -> torch.Tensor:
    """Texture on a strong left-to-right ramp, with a hard edge a third of the way across."""
    x = _texture(2, 3, h, w, seed=1) * 0.3
    ramp = torch.linspace(0, 0.6, w, dtype=x.dtype)
    edge = (torch.arange(w) >= w // 3).to(x.dtype) * 0.1
    return (x + ramp + edge).clamp(0, 1)


# -- seam_error -------------------------------------------------------------------------


def test_a_ramp_scores_its_side_minus_one_and_a_constant_zero():
    ramp = torch.linspace(0, 1, 128).expand(2, 3, 64, 128)
    assert seam_error(ramp).shape == (2,)
    assert seam_error(ramp).tolist() == pytest.approx([127.0, 127.0], rel=1e-4)
    assert seam_error(ramp.transpose(-1, -2)).tolist() == pytest.approx([127.0, 127.0], rel=1e-4)
    assert seam_error(torch.full((1, 1, 64, 64), 0.3)).tolist() == [0.0]


def test_a_periodic_texture_scores_about_one_wherever_it_is_cut():
    x = _texture(3, 3, 128, 128, seed=2, periodic=True)
    for shift in (0, 17, 64):
        s = seam_error(torch.roll(x, (shift, 2 * shift), dims=(-2, -1)))
        assert ((s > 0.8) & (s < 1.25)).all(), (shift, s)
    assert (seam_error(_texture(3, 3, 128, 128, seed=2)) > 2).all()  # the same, not periodic


# -- make_tileable_map ------------------------------------------------------------------


def test_a_strong_ramp_and_edge_tile_after_and_not_before():
    x = _hard_seam_map()
    before, after = seam_error(x), seam_error(make_tileable_map(x))
    assert (before > 20).all(), before
    assert (after < 1.5).all(), after


def test_no_seam_moves_inside_the_map():
    """Ramps on both axes: the wrap seams were steps of 0.5. Afterwards no step anywhere,
    wrap included, exceeds the steepest slope of the cross-fade (1.5 / 32 px) times the
    mismatch (0.5) plus the ramp's own step. A single pass with a copy shifted on both axes
    would bring that copy's middle seam out to the borders."""
    i = torch.linspace(0, 0.5, 128, dtype=torch.float64)
    x = (i[None, :] + i[:, None]).expand(1, 1, 128, 128)
    out = make_tileable_map(x)
    wrapped = torch.cat([out, out[..., :1, :]], dim=-2)
    wrapped = torch.cat([wrapped, wrapped[..., :1]], dim=-1)
    steps = torch.stack([wrapped.diff(dim=-1)[..., :-1, :], wrapped.diff(dim=-2)[..., :, :-1]])
    assert float(steps.abs().max()) < 1.5 / 32 * 0.5 + 0.5 / 127 + 1e-9
    assert float(x.diff(dim=-1).abs().max()) < 0.01  # the original's steps were small inside


@pytest.mark.parametrize("w", [64, 65, 128, 127])
def test_the_wrap_pairs_are_the_originals_middle_neighbours(w):
    """For a map that varies along x only, the output's last and first columns are exactly
    the original's two middle columns, ``W - 1 - W // 2`` and the next (the y pass leaves
    rows that are all alike alone)."""
    x = torch.rand(1, 2, 1, w, generator=torch.Generator().manual_seed(w)).expand(1, 2, 80, w)
    out = make_tileable_map(x)
    assert torch.allclose(out[..., -1], x[..., w - 1 - w // 2])
    assert torch.allclose(out[..., 0], x[..., w - w // 2])


@pytest.mark.parametrize("blend, band", [(0.25, 24), (0.125, 12), (0.5, 47)])
def test_the_middle_is_the_original_and_the_band_is_as_wide_as_promised(blend, band):
    x = _texture(1, 3, 96, 96, seed=3)
    out = make_tileable_map(x, blend)
    inner = slice(band, 96 - band)
    assert torch.equal(out[..., inner, inner], x[..., inner, inner])
    for edge in (band - 1, 96 - band):  # the first pixel inside the band on each side
        assert not torch.allclose(out[..., edge, inner], x[..., edge, inner])
        assert not torch.allclose(out[..., inner, edge], x[..., inner, edge])


def test_the_mean_is_kept_and_values_stay_within_the_inputs_range():
    """The mean moves by the band's share of ``mean(centre) - mean(borders)``: for uniform
    noise (std 0.29) at this size a fluctuation with a standard deviation of 0.002 (measured
    over 300 seeds), so 0.01 is 5 of them; a blend whose weights did not sum to 1, or that
    favoured one copy, would move it by far more."""
    x = torch.rand(2, 3, 128, 160, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    out = make_tileable_map(x)
    assert out.shape == x.shape and out.dtype == x.dtype
    shift = (out.mean(dim=(-2, -1)) - x.mean(dim=(-2, -1))).abs()
    assert (shift < 0.01).all(), shift
    assert out.amin() >= x.amin() and out.amax() <= x.amax()  # convex combinations
    spread = out.std(dim=(-2, -1)) / x.std(dim=(-2, -1))
    assert ((spread > 0.7) & (spread < 1.0)).all(), spread  # contrast lost in the band only


# -- make_tileable ----------------------------------------------------------------------


def test_a_material_tiles_with_unit_normals_and_the_same_blend_in_every_map():
    m = random_svbrdf(2, 96, seed=5)
    m = SVBRDF(m.normal, m.diffuse, m.diffuse[:, 1:2], m.diffuse, validate=False)
    hard = _hard_seam_map(96, 96).float()
    m = SVBRDF(m.normal, hard, m.roughness, m.specular)
    out = make_tileable(m)
    assert out.shape == m.shape and out.dtype == m.dtype
    assert torch.allclose(out.normal.norm(dim=1), torch.ones(2, 96, 96), atol=1e-6)
    assert torch.allclose(out.roughness, out.specular[:, 1:2])
    assert (seam_error(out.diffuse) < 1.5).all() and (seam_error(m.diffuse) > 20).all()
    inner = slice(24, 72)
    for name in ("diffuse", "roughness", "specular"):
        assert torch.equal(getattr(out, name)[..., inner, inner], getattr(m, name)[..., inner, inner])
    assert torch.allclose(out.normal[..., inner, inner], m.normal[..., inner, inner], atol=1e-6)
    SVBRDF(*out.maps().values())  # the ranges hold: validation passes


def _opposite_grazing_normals(size: int) -> SVBRDF:
    """Left half (1, 0, 0), right half (-1, 0, 0): the copy half a period away is always the
    opposite normal, so the blend meets a zero vector where the weight is 1/2."""
    m = SVBRDF.constant(1, size)
    n = torch.zeros(1, 3, size, size)
    n[:, 0, :, : size // 2] = 1
    n[:, 0, :, size // 2 :] = -1
    return SVBRDF(n, m.diffuse, m.roughness, m.specular)


def _extremes(size: int) -> SVBRDF:
    """Every value at 0 or 1 on a checkerboard; normals along +z or grazing along y."""
    i = torch.arange(size)
    board = ((i[:, None] // 8 + i[None, :] // 8) % 2).float().expand(1, 1, size, size)
    n = torch.cat([torch.zeros_like(board), board, 1 - board], dim=1)
    return SVBRDF(n, board.expand(1, 3, -1, -1), 1 - board, board.expand(1, 3, -1, -1))


@pytest.mark.parametrize(
    "make",
    [
        lambda s: SVBRDF.constant(2, s),
        lambda s: SVBRDF.constant(1, s, diffuse=(0, 0, 0), roughness=1.0, specular=(1, 1, 1)),
        _extremes,
        _opposite_grazing_normals,
    ],
    ids=["constant", "constant-extremes", "checker-0-1", "opposite-normals"],
)
@pytest.mark.parametrize("size", [MIN_TILEABLE_SIDE, MIN_TILEABLE_SIDE + 1, 128])
def test_hard_cases_are_finite_and_bounded_forward_and_backward(make, size):
    m = make(size)
    leaves = [t.detach().clone().requires_grad_(True) for t in m.maps().values()]
    out = make_tileable(SVBRDF(*leaves, validate=False))
    g = torch.Generator().manual_seed(size)
    loss = 0
    for t in out.maps().values():
        assert torch.isfinite(t).all()
        loss = loss + (t * (torch.rand(t.shape, generator=g) * 2 - 1)).sum()
    assert torch.allclose(out.normal.norm(dim=1), torch.ones(out.shape), atol=1e-6)
    SVBRDF(*(t.detach() for t in out.maps().values()))  # in range, no clamp needed
    loss.backward()
    bounds = {"normal": 4e4, "diffuse": 4.0, "roughness": 4.0, "specular": 4.0}
    for name, t in zip(out.maps(), leaves, strict=True):
        assert torch.isfinite(t.grad).all(), name
        assert float(t.grad.abs().max()) <= bounds[name] + 1e-5, name


def test_a_constant_material_comes_back_unchanged():
    m = SVBRDF.constant(1, 64, diffuse=(0.1, 0.5, 0.9), roughness=0.3, normal=(0.2, -0.1, 1))
    out = make_tileable(m)
    for name, t in m.maps().items():
        assert torch.allclose(getattr(out, name), t, atol=1e-6), name


# -- bad input --------------------------------------------------------------------------


@pytest.mark.parametrize("h, w", [(MIN_TILEABLE_SIDE - 1, 128), (128, MIN_TILEABLE_SIDE - 1), (16, 16)])
def test_too_small_maps_are_refused_with_their_size_and_what_to_do(h, w):
    with pytest.raises(MapError) as e:
        make_tileable(SVBRDF.constant(1, (h, w)))
    msg = str(e.value)
    assert f"{w}x{h}" in msg and f"{MIN_TILEABLE_SIDE} px" in msg and "resize" in msg
    assert "\n" not in msg
    with pytest.raises(MapError, match=f"{w}x{h}"):
        make_tileable_map(torch.zeros(1, 1, h, w))


@pytest.mark.parametrize("blend", [0.0, -0.1, 0.6, float("nan")])
def test_a_blend_outside_the_open_half_is_refused(blend):
    with pytest.raises(MapError, match=r"blend .*\(0, 0\.5\]"):
        make_tileable(SVBRDF.constant(1, 64), blend=blend)


def test_a_map_that_is_not_4d_is_refused():
    with pytest.raises(MapError, match=r"\(B, C, H, W\)"):
        make_tileable_map(torch.zeros(3, 64, 64))
    with pytest.raises(MapError, match=r"\(B, C, H, W\)"):
        seam_error(torch.zeros(64, 64))
