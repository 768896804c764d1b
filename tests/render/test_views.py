"""One material refined against several photos (``svbrdf_render.refine_views``): more views tell
relief and albedo apart where one cannot, a view left out is predicted better, the views render
in one call, one view is ``refine_maps`` itself, and the hard cases stay finite."""

from __future__ import annotations

import pytest
import torch

from svbrdf_render import SVBRDF, Camera, PointLight, Scene, refine_maps, refine_views, render
from svbrdf_render.compare import map_rmse
from svbrdf_render.errors import MapError, SceneError
from svbrdf_render.examples import example_material
from svbrdf_render.refinement import views as views_module
from svbrdf_render.refinement.refine import RefineSettings, _Parameters
from svbrdf_render.refinement.views import _ViewsLoss, _Views, stack_views

SIZE = 32
#: Five views of a calibrated capture: camera and light together, off the axis in turn.
POSITIONS = [(0.0, 0.0, 3.0), (1.5, 0.5, 3.0), (-1.2, 1.0, 2.8), (0.3, -1.5, 3.2), (-1.0, -1.0, 2.5)]
SCENES = [Scene(Camera(torch.tensor(p)), (PointLight(torch.tensor(p), 12.0),)) for p in POSITIONS]
START = SVBRDF.constant(1, SIZE, diffuse=(0.3,) * 3, roughness=0.5, specular=(0.05,) * 3)


@pytest.fixture(scope="module")
def truth() -> SVBRDF:
    return example_material("leather", SIZE)


@pytest.fixture(scope="module")
def photos(truth) -> torch.Tensor:
    return render(truth, stack_views(SCENES))[0].clamp(0, 1)


def rmse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).square().mean().sqrt())


def assert_valid(maps: SVBRDF) -> None:
    for name, t in maps.maps().items():
        assert bool(torch.isfinite(t).all()), name
    assert torch.allclose(maps.normal.norm(dim=1), torch.ones(1), atol=1e-5)
    assert bool((maps.normal[:, 2] > 0).all())
    for name in ("diffuse", "roughness", "specular"):
        t = getattr(maps, name)
        assert bool(((t >= 0) & (t <= 1)).all()), name


# -- what it does ---------------------------------------------------------------------------------


def test_three_views_recover_relief_and_albedo_better_than_one_and_predict_a_view_left_out(truth, photos):
    """From constant maps: three views get closer to the true normals and diffuse than the
    first view alone, and the fifth view, never refined against, is re-rendered better."""
    one = refine_views(photos[:1], START, SCENES[:1], steps=80, backend="eager")
    three = refine_views(photos[:3], START, SCENES[:3], steps=80, backend="eager")
    e1, e3 = map_rmse(one.svbrdf, truth), map_rmse(three.svbrdf, truth)
    assert float(e3["normal"][0]) < float(e1["normal"][0]) - 0.005
    assert float(e3["diffuse"][0]) < 0.7 * float(e1["diffuse"][0])
    held = [rmse(render(m, SCENES[4]).clamp(0, 1), photos[4]) for m in (START, one.svbrdf, three.svbrdf)]
    assert held[2] < held[1] < held[0]
    assert three.residuals.shape == (3,) and bool((three.residuals < 0.05).all())
    assert three.steps == 80 and three.losses.shape == (80,)
    assert float(three.losses[-1]) < float(three.losses[0])
    assert torch.equal(three.gains, torch.ones(3))  # fixed: the light's power is known
    assert_valid(three.svbrdf)


def test_a_list_of_views_is_stacked_and_rendered_in_one_call(photos, monkeypatch):
    calls = []
    real = views_module.render
    monkeypatch.setattr(views_module, "render", lambda *a, **k: calls.append(1) or real(*a, **k))
    stacked = stack_views(SCENES[:3])
    assert tuple(stacked.config_shape) == (1, 3)
    a = refine_views(photos[:3], START, SCENES[:3], steps=3, backend="eager")
    assert isinstance(a.scenes, Scene) and tuple(a.scenes.config_shape) == (1, 3)
    assert len(calls) == 4  # 3 steps and the residuals, each one render of the three views
    b = refine_views(photos[:3], START, stacked, steps=3, backend="eager")
    for name, t in a.svbrdf.maps().items():
        assert torch.equal(t, getattr(b.svbrdf, name)), name


def test_views_that_cannot_stack_are_rendered_one_by_one(photos):
    """A light of another colour is no configuration dimension: each view renders alone, and
    the result is that of the same views stacked (colour aside)."""
    warm = torch.tensor([1.0, 0.9, 0.8])
    odd = Scene(SCENES[1].camera, (PointLight(SCENES[1].camera.position, 12.0, warm),))
    assert stack_views([SCENES[0], odd]) is None
    views = _Views([SCENES[0], odd], torch.device("cpu"))
    got = views.render(START, "eager")
    assert got.shape == (2, 3, SIZE, SIZE)
    assert torch.allclose(got[1], render(START, odd)[0])
    out = refine_views(photos[:2], START, [SCENES[0], odd], steps=2, backend="eager")
    assert isinstance(out.scenes, list) and out.residuals.shape == (2,)


def test_one_view_is_refine_maps_without_rings(truth, photos):
    settings = RefineSettings(rings=0.0)
    views = refine_views(photos[1:2], START, SCENES[1], steps=30, settings=settings, backend="eager")
    maps = refine_maps(photos[1:2], START, scene=SCENES[1], steps=30, settings=settings, backend="eager")
    for name, t in views.svbrdf.maps().items():
        assert torch.allclose(t, getattr(maps.svbrdf, name), atol=1e-5), name
    assert torch.allclose(views.losses, maps.losses, atol=1e-6)


def test_free_gains_find_each_views_exposure_with_the_anchor_held(photos):
    """View 1 photographed 1.5 times brighter (an exposure not recorded): with free gains its
    gain goes toward 1.5 while view 0, the anchor, stays at 1."""
    brighter = torch.stack([photos[0], (photos[1] * 1.5).clamp(0, 1), photos[2]])
    out = refine_views(brighter, START, SCENES[:3], gains="free", steps=120, backend="eager")
    assert float(out.gains[0]) == 1.0
    assert 1.25 < float(out.gains[1]) < 1.75 and 0.8 < float(out.gains[2]) < 1.2
    anchored = refine_views(brighter, START, SCENES[:3], gains="free", anchor=[0, 1, 2], steps=2,
                            backend="eager")
    assert torch.equal(anchored.gains, torch.ones(3))


def test_masks_leave_unseen_pixels_out_of_the_fit_and_the_residuals(photos):
    masks = torch.ones(3, 1, SIZE, SIZE)
    masks[1, :, :, : SIZE // 2] = 0
    spoiled = photos[:3].clone()
    spoiled[1, :, :, : SIZE // 2] = 1.0  # what the mask hides is not the material
    masked = refine_views(spoiled, START, SCENES[:3], masks=masks, steps=40, backend="eager")
    clean = refine_views(photos[:3], START, SCENES[:3], masks=masks, steps=40, backend="eager")
    for name, t in masked.svbrdf.maps().items():
        assert torch.allclose(t, getattr(clean.svbrdf, name), atol=1e-5), name
    assert torch.allclose(masked.residuals, clean.residuals, atol=1e-6)


# -- hard cases: forward and backward finite and bounded -----------------------------------------


def _hard(case: str, photos: torch.Tensor):
    photos, masks = photos[:3].clone(), None
    if case == "a view all black":
        photos[1] = 0.0
    elif case == "a view all clipped":
        photos[1] = 1.0
    elif case == "a mask all zero":
        masks = torch.ones(3, 1, SIZE, SIZE)
        masks[2] = 0.0
    elif case == "every mask zero":
        masks = torch.zeros(3, 1, SIZE, SIZE)
    return photos, masks


CASES = ["a view all black", "a view all clipped", "a mask all zero", "every mask zero"]


@pytest.mark.parametrize("gains", ["fixed", "free"])
@pytest.mark.parametrize("case", CASES)
def test_hard_cases_are_finite_and_bounded_forward_and_backward(case, gains, photos):
    photos, masks = _hard(case, photos)
    settings = RefineSettings()
    params = _Parameters(START, settings.coarse)
    log_gain = torch.zeros(3, requires_grad=True)
    free = torch.tensor([0.0, 1.0, 1.0]) if gains == "free" else torch.zeros(3)
    views = _Views(SCENES[:3], torch.device("cpu"))
    loss = _ViewsLoss(photos, masks, START, views, settings, "eager", log_gain, free)(params.svbrdf())
    loss.backward()
    assert bool(torch.isfinite(loss.detach())) and 0 <= float(loss.detach()) < 20
    grads = [d.grad for ds in params.delta.values() for d in ds] + [log_gain.grad]
    for g in grads:
        assert g is None or (bool(torch.isfinite(g).all()) and float(g.abs().max()) < 1e3)
    out = refine_views(photos, START, SCENES[:3], masks=masks, gains=gains, steps=5, backend="eager")
    assert_valid(out.svbrdf)
    assert bool(torch.isfinite(out.losses).all()) and bool(torch.isfinite(out.gains).all())
    seen = torch.ones(3, dtype=torch.bool) if masks is None else masks.flatten(1).sum(1) > 0
    assert bool(torch.isfinite(out.residuals[seen]).all()) and bool(torch.isnan(out.residuals[~seen]).all())
    assert bool((out.residuals[seen] <= 1).all())


def test_a_budget_of_nothing_returns_the_start_and_its_residuals(photos):
    out = refine_views(photos[:2], START, SCENES[:2], steps=0)
    assert out.steps == 0 and out.losses.shape == (0,) and out.svbrdf.size == (SIZE, SIZE)
    want = [rmse(render(START, s).clamp(0, 1), p) for s, p in zip(SCENES[:2], photos[:2])]
    assert torch.allclose(out.residuals, torch.tensor(want), atol=1e-6)


# -- refusals --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, error, says",
    [
        ({"photos": torch.rand(2, 3, SIZE, SIZE)}, MapError, "2 photo(s) but 3 view(s)"),
        ({"photos": torch.rand(3, 1, SIZE, SIZE)}, MapError, "expected photos (K, 3, H, W)"),
        ({"start": SVBRDF.constant(2, SIZE)}, MapError, "ONE material"),
        ({"masks": torch.ones(3, 1, 8, 8)}, MapError, "masks must be (3, 1, 32, 32)"),
        ({"masks": -torch.ones(3, 1, SIZE, SIZE)}, MapError, "finite weights >= 0"),
        ({"gains": "auto"}, ValueError, "gains must be one of"),
        ({"gains": "free", "anchor": [3]}, ValueError, "anchor names view 3"),
        ({"scenes": Scene(Camera(torch.zeros(2, 3, 3) + 3.0))}, SceneError, "shape (1, K)"),
        ({"scenes": [SCENES[0], stack_views(SCENES[:2])]}, SceneError, "scenes[1]"),
        ({"scenes": []}, SceneError, "a list of K one-view scenes"),
        ({"steps": -1}, ValueError, "steps must be"),
    ],
)
def test_bad_input_is_refused_in_one_line(kwargs, error, says, photos):
    args = {"photos": photos[:3], "start": START, "scenes": SCENES[:3], **kwargs}
    with pytest.raises(error) as e:
        refine_views(args.pop("photos"), args.pop("start"), args.pop("scenes"), backend="eager", **args)
    assert says in str(e.value) and "\n" not in str(e.value)
