"""Refinement (inverse rendering of maps): valid at every step, finite on the hard cases, closer
to the photo, the highlight kept out of the diffuse map, deterministic, bounded by its budget."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import SVBRDF, Scene, refine_maps, render
from svbrdf_render.errors import MapError, SceneError
from svbrdf_render.refinement.fit import axis_flash
from svbrdf_render.refinement.refine import RefineLoss, RefineSettings, _Parameters

SCENE = Scene.flash(intensity=15.0)


def photo_of(maps: SVBRDF, scene: Scene = SCENE) -> torch.Tensor:
    return render(maps, scene).clamp(0, 1)


def assert_valid(maps: SVBRDF) -> None:
    for name, t in maps.maps().items():
        assert bool(torch.isfinite(t).all()), name
    n = maps.normal
    assert torch.allclose(n.norm(dim=1), torch.ones_like(n[:, 0]), atol=1e-5)
    assert bool((n[:, 2] > 0).all())
    for name in ("diffuse", "roughness", "specular"):
        t = getattr(maps, name)
        assert bool(((t >= 0) & (t <= 1)).all()), name


def photo_rmse(maps: SVBRDF, photo: torch.Tensor, scene: Scene = SCENE) -> float:
    return float((photo_of(maps, scene) - photo).square().mean().sqrt())


# -- what it does ---------------------------------------------------------------------------


def test_refined_maps_explain_the_photo_better_than_the_start():
    truth = random_svbrdf(2, 32, seed=1, roughness=(0.3, 0.6))
    photo = photo_of(truth)
    start = SVBRDF.constant(2, 32, diffuse=(0.3, 0.3, 0.3), roughness=0.5, specular=(0.05,) * 3)
    out = refine_maps(photo, start, scene=SCENE, steps=60, backend="eager")
    assert out.steps == 60 and out.losses.shape == (60,)
    assert float(out.losses[-1]) < float(out.losses[0])
    assert photo_rmse(out.svbrdf, photo) < 0.5 * photo_rmse(start, photo)
    assert_valid(out.svbrdf)


def test_maps_of_another_size_are_refined_at_the_photo_size():
    photo = photo_of(random_svbrdf(1, 48, seed=2))
    out = refine_maps(photo, SVBRDF.constant(1, 16), scene=SCENE, steps=3, backend="eager")
    assert out.svbrdf.size == (48, 48)


def test_the_prior_holds_the_maps_it_weighs():
    truth = random_svbrdf(1, 24, seed=3)
    photo = photo_of(truth)
    start = SVBRDF.constant(1, 24)
    free = refine_maps(photo, start, scene=SCENE, steps=40, backend="eager",
                       settings=RefineSettings(prior={}))  # fmt: skip
    held = refine_maps(photo, start, scene=SCENE, steps=40, backend="eager",
                       settings=RefineSettings(prior={"diffuse": 100.0}))  # fmt: skip
    moved = lambda r: float((r.svbrdf.diffuse - start.diffuse).abs().mean())  # noqa: E731
    assert moved(held) < 0.2 * moved(free)


SHINY = SVBRDF.constant(1, 64, diffuse=(0.25, 0.2, 0.15), roughness=0.25, specular=(0.3,) * 3)
#: A wrong guess at SHINY: too rough, too little specular.
DULL = SVBRDF.constant(1, 64, diffuse=(0.25, 0.2, 0.15), roughness=0.6, specular=(0.08,) * 3)


def centre_to_edge(maps: SVBRDF) -> float:
    """Mean diffuse in the centre (under the flash) over the mean along the top and bottom edges."""
    d = maps.diffuse[0].mean(0)
    c = d.shape[-1] // 2
    centre = d[c - 4 : c + 4, c - 4 : c + 4].mean()
    edge = torch.cat([d[:6].flatten(), d[-6:].flatten()]).mean()
    return float(centre / edge)


def test_the_highlight_is_not_baked_into_the_diffuse_map():
    """A uniform shiny material: its photo has a bright, clipped highlight at the centre.
    Started from a wrong guess, the refined diffuse must stay uniform. The control, the same
    refinement without the rings term (``rings=0``), shows the test can fail: there the
    highlight ends up in the diffuse."""
    photo = photo_of(SHINY)
    out = refine_maps(photo, DULL, scene=SCENE, steps=150, backend="eager")
    baked = refine_maps(photo, DULL, scene=SCENE, steps=150, backend="eager", settings=RefineSettings(rings=0.0))
    assert centre_to_edge(baked.svbrdf) > 1.3
    assert 0.93 < centre_to_edge(out.svbrdf) < 1.07
    assert photo_rmse(out.svbrdf, photo) < photo_rmse(DULL, photo)


def test_a_dark_hole_where_the_highlight_was_is_filled():
    """Networks often leave a dark hole in the diffuse under the highlight; the photo cannot
    show it (it is clipped there), so only the prior that the diffuse's mean does not depend on
    the distance to the flash fills it. Without it (``rings=0``) the hole stays."""
    yy, xx = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    dip = 1 - 0.7 * torch.exp(-(((yy - 31.5) ** 2 + (xx - 31.5) ** 2).sqrt() / 8) ** 2)
    holed = SVBRDF(SHINY.normal, SHINY.diffuse * dip, SHINY.roughness, SHINY.specular)
    photo = photo_of(SHINY)
    assert centre_to_edge(holed) < 0.45
    out = refine_maps(photo, holed, scene=SCENE, steps=100, backend="eager")
    kept = refine_maps(photo, holed, scene=SCENE, steps=100, backend="eager", settings=RefineSettings(rings=0.0))
    assert centre_to_edge(out.svbrdf) > 0.85
    assert centre_to_edge(kept.svbrdf) < 0.5


def test_axis_flash_recovers_the_intensity_of_a_known_material():
    truth = random_svbrdf(2, 32, seed=4)
    photos = torch.stack([photo_of(truth[0], Scene.flash(intensity=9.0))[0],
                          photo_of(truth[1], Scene.flash(intensity=21.0))[0]])  # fmt: skip
    scene = axis_flash(truth, photos)
    assert torch.allclose(scene.lights[0].intensity.flatten(), torch.tensor([9.0, 21.0]), rtol=0.02)


def test_without_a_scene_each_material_gets_its_own_flash():
    truth = random_svbrdf(2, 24, seed=5)
    photos = torch.cat([photo_of(truth[0], Scene.flash(intensity=8.0)),
                        photo_of(truth[1], Scene.flash(intensity=16.0))])  # fmt: skip
    out = refine_maps(photos, truth, steps=5, backend="eager")
    assert out.svbrdf.batch_size == 2
    assert torch.allclose(out.scene.lights[0].intensity.flatten(), torch.tensor([8.0, 16.0]), rtol=0.02)
    assert out.scene.config_shape == (2, 1)


def test_deterministic():
    photo = photo_of(random_svbrdf(1, 24, seed=6))
    runs = [refine_maps(photo, SVBRDF.constant(1, 24), steps=20, backend="eager") for _ in range(2)]
    assert torch.equal(runs[0].svbrdf.pack(), runs[1].svbrdf.pack())
    assert torch.equal(runs[0].losses, runs[1].losses)


# -- budget and progress ------------------------------------------------------------------------


def test_callback_sees_every_step():
    seen = []
    photo = photo_of(random_svbrdf(1, 16, seed=7))
    refine_maps(photo, SVBRDF.constant(1, 16), scene=SCENE, steps=7, backend="eager",
                callback=lambda *a: seen.append(a))  # fmt: skip
    assert [s[0] for s in seen] == list(range(1, 8))
    assert all(s[1] == 7 and s[2] == s[2] for s in seen)


def test_zero_budget_returns_the_start_at_the_photo_size():
    photo = photo_of(random_svbrdf(1, 32, seed=8))
    start = SVBRDF.constant(1, 32)
    for out in (refine_maps(photo, start, steps=0), refine_maps(photo, start, steps=50, seconds=0.0)):
        assert out.steps == 0
        assert torch.equal(out.svbrdf.diffuse, start.diffuse)


def test_a_time_budget_stops_early():
    photo = photo_of(random_svbrdf(1, 32, seed=9))
    out = refine_maps(photo, SVBRDF.constant(1, 32), scene=SCENE, steps=100_000, seconds=0.3, backend="eager")
    assert 1 <= out.steps < 100_000


def test_interrupt_propagates_and_returns_nothing():
    def stop(step, total, loss):
        if step == 3:
            raise KeyboardInterrupt

    photo = photo_of(random_svbrdf(1, 16, seed=10))
    with pytest.raises(KeyboardInterrupt):
        refine_maps(photo, SVBRDF.constant(1, 16), scene=SCENE, steps=10, backend="eager", callback=stop)


# -- hard cases: forward and backward finite ------------------------------------------------------


def _grads(photo: torch.Tensor, start: SVBRDF) -> list[torch.Tensor]:
    params = _Parameters(start, coarse=8)
    loss = RefineLoss(photo, start, SCENE, RefineSettings(), "eager")(params.svbrdf())
    loss.backward()
    assert bool(torch.isfinite(loss))
    return [d.grad for deltas in params.delta.values() for d in deltas]


def _grazing(size: int) -> SVBRDF:
    m = SVBRDF.constant(1, size, roughness=0.0)
    n = m.normal.clone()
    n[:, :, : size // 2] = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)  # grazing
    n[:, :, size // 2 :, : size // 2] = torch.tensor([0.0, 0.6, -0.8]).view(1, 3, 1, 1)  # facing away
    return SVBRDF(n, m.diffuse, m.roughness, m.specular)


HARD = {
    "black photo": lambda: (torch.zeros(1, 3, 16, 16), SVBRDF.constant(1, 16)),
    "saturated photo": lambda: (torch.ones(1, 3, 16, 16), SVBRDF.constant(1, 16)),
    "1x1 photo": lambda: (torch.full((1, 3, 1, 1), 0.4), SVBRDF.constant(1, 1)),
    "2x2 photo": lambda: (torch.rand(1, 3, 2, 2, generator=torch.Generator().manual_seed(0)), SVBRDF.constant(1, 2)),
    "roughness 0": lambda: (torch.full((1, 3, 16, 16), 0.3), SVBRDF.constant(1, 16, roughness=0.0)),
    "roughness 1": lambda: (torch.full((1, 3, 16, 16), 0.3), SVBRDF.constant(1, 16, roughness=1.0)),
    "albedos 0 and 1": lambda: (
        torch.full((1, 3, 16, 16), 0.3),
        SVBRDF.constant(1, 16, diffuse=(0.0, 1.0, 0.0), specular=(1.0, 0.0, 1.0)),
    ),
    "grazing normals": lambda: (torch.full((1, 3, 16, 16), 0.3), _grazing(16)),
    "photo out of range": lambda: (torch.full((1, 3, 8, 8), 7.0), SVBRDF.constant(1, 8)),
}


@pytest.mark.parametrize("case", sorted(HARD))
def test_hard_cases_are_finite_forward_and_backward(case):
    photo, start = HARD[case]()
    for g in _grads(photo, start):
        assert g is not None and bool(torch.isfinite(g).all())
        assert float(g.abs().max()) < 1e4
    out = refine_maps(photo, start, scene=SCENE, steps=10, backend="eager")
    assert_valid(out.svbrdf)
    assert bool(torch.isfinite(out.losses).all())


# -- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"steps": -1}, ValueError, "steps"),
        ({"steps": 2.5}, ValueError, "steps"),
        ({"steps": True}, ValueError, "steps"),
        ({"seconds": -1.0}, ValueError, "seconds"),
        ({"seconds": float("nan")}, ValueError, "seconds"),
        ({"backend": "gpu"}, ValueError, "backend"),
        ({"flash": "sun"}, ValueError, "flash"),
        ({"scene": "flash"}, SceneError, "Scene"),
        ({"scene": Scene(lights=Scene.flash().lights, camera=Scene.flash().camera).__class__(
            camera=Scene.flash().camera.__class__(torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])))},
         SceneError, "one view"),
    ],
)  # fmt: skip
def test_bad_arguments_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        refine_maps(torch.zeros(1, 3, 8, 8), SVBRDF.constant(1, 8), **kwargs)


@pytest.mark.parametrize(
    ("photo", "match"),
    [
        (torch.zeros(3, 3, 8, 8), "3 photo"),
        (torch.zeros(1, 4, 8, 8), "colour channels"),
        (torch.zeros(8, 8), "expected a photo"),
        (torch.full((1, 3, 8, 8), float("nan")), "NaN"),
    ],
)
def test_bad_photos_are_refused(photo, match):
    with pytest.raises(MapError, match=match):
        refine_maps(photo, SVBRDF.constant(1, 8), steps=1)


@pytest.mark.parametrize(
    "bad",
    [{"lr": 0.0}, {"eps": 0.0}, {"prior": {"albedo": 1.0}}, {"prior": {"normal": -1.0}}, {"coarse": -1},
     {"rings": -1.0}, {"dielectric": -0.1}],
)  # fmt: skip
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        RefineSettings(**bad)


@pytest.mark.slow
def test_compiled_backend_refines_like_eager():
    truth = random_svbrdf(1, 32, seed=11)
    photo = photo_of(truth)
    start = SVBRDF.constant(1, 32)
    a = refine_maps(photo, start, scene=SCENE, steps=15, backend="eager")
    b = refine_maps(photo, start, scene=SCENE, steps=15, backend="compiled")
    assert torch.allclose(a.losses, b.losses, rtol=1e-3, atol=1e-5)
    assert torch.allclose(a.svbrdf.pack(), b.svbrdf.pack(), atol=1e-3)
