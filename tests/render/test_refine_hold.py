"""``RefineSettings(hold=...)``: maps held at the start's values are no free parameter of a
refinement (what ``svbrdf-models predict --metal none`` holds the specular with), while the
others still move and the loss still falls."""

from __future__ import annotations

import pytest
import torch

from svbrdf_render import SVBRDF, RefineSettings, Scene, refine_maps, refine_views, render


def _photo_and_start():
    truth = SVBRDF.constant(1, 32, diffuse=(0.05, 0.04, 0.03), roughness=0.3, specular=(0.04, 0.04, 0.04))
    photo = render(truth, Scene.flash(intensity=10.0)).clamp(0, 1)
    start = SVBRDF.constant(1, 32, diffuse=(0.3, 0.3, 0.3), roughness=0.7, specular=(0.04, 0.04, 0.04))
    return photo, start


def test_a_held_map_stays_at_the_start_while_the_others_move_and_the_loss_falls():
    photo, start = _photo_and_start()
    held = refine_maps(photo, start, steps=40, backend="eager", settings=RefineSettings(hold=("specular",)))
    free = refine_maps(photo, start, steps=40, backend="eager")
    assert torch.allclose(held.svbrdf.specular, start.specular, atol=1e-6)
    assert not torch.allclose(free.svbrdf.specular, start.specular, atol=1e-4)  # unheld, it moves
    assert float(held.losses[-1]) < float(held.losses[0])
    assert not torch.allclose(held.svbrdf.roughness, start.roughness, atol=1e-3)


def test_nothing_held_is_the_default_refinement_bit_for_bit():
    photo, start = _photo_and_start()
    a = refine_maps(photo, start, steps=5, backend="eager", settings=RefineSettings(hold=()))
    b = refine_maps(photo, start, steps=5, backend="eager")
    for name, t in a.svbrdf.maps().items():
        assert torch.equal(t, getattr(b.svbrdf, name)), name


def test_several_views_hold_it_too():
    photo, start = _photo_and_start()
    scene = Scene.flash(intensity=10.0)
    result = refine_views(photo.expand(2, -1, -1, -1), start, [scene, scene], steps=5, backend="eager",
                          settings=RefineSettings(hold=("specular",)))  # fmt: skip
    assert torch.allclose(result.svbrdf.specular, start.specular, atol=1e-6)


def test_holding_an_unknown_map_is_refused():
    with pytest.raises(ValueError, match="shine"):
        RefineSettings(hold=("shine",))
