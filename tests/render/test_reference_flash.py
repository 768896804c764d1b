"""A region of known albedo: the flash read off it (``reference_flash``), and maps held at known
values during a refinement (``refine_maps(held=...)``). Hard cases finite; held pixels exact."""

from __future__ import annotations

import math

import pytest
import torch

from svbrdf_render import SVBRDF, MapError, Scene, refine_maps, render
from svbrdf_render.examples import example_material
from svbrdf_render.refinement.fit import CARD_F0, card_maps, flash_scene, reference_flash


def _mask(size=32, box=(0, 0, 12, 12)):
    t, l, b, r = box
    m = torch.zeros(1, 1, size, size, dtype=torch.bool)
    m[..., t:b, l:r] = True
    return m


def test_a_card_reflects_its_albedo():
    """The card's diffuse map is albedo / (1 - F0): what the Des18 term reflects is the albedo."""
    card = card_maps(0.18, (4, 4))
    assert float(card.diffuse[0, 0, 0, 0]) * (1 - CARD_F0) == pytest.approx(0.18)
    assert torch.all(card.normal[:, 2] == 1) and float(card.specular.max()) == pytest.approx(CARD_F0)


@pytest.mark.parametrize(
    ("photo", "clipped", "dark"),
    [(torch.zeros(1, 3, 32, 32), 0.0, 1.0), (torch.ones(1, 3, 32, 32), 1.0, 0.0)],
)
def test_black_and_white_photos_say_so_and_stay_finite(photo, clipped, dark):
    got = reference_flash(photo, _mask(), 0.18, torch.tensor([0.0, 0.0, 2.2]))
    assert float(got.clipped[0]) == clipped and float(got.dark[0]) == dark and int(got.pixels[0]) == 0
    assert torch.isfinite(got.intensity).all() and torch.isfinite(got.color).all()


def test_an_empty_region_reads_nothing():
    photo = render(example_material("tiles", 32), Scene.flash(intensity=10.0)).clamp(0, 1)
    got = reference_flash(photo, torch.zeros(1, 1, 32, 32, dtype=torch.bool), 0.18, torch.tensor([0.0, 0.0, 2.2]))
    assert int(got.pixels[0]) == 0 and torch.isfinite(got.intensity).all()


def test_held_pixels_stay_at_their_maps_and_the_rest_moves():
    truth = example_material("tiles", 32)
    photo = render(truth, Scene.flash(intensity=10.0)).clamp(0, 1)
    start = SVBRDF.constant(1, 32)
    card = card_maps(0.5, (32, 32))
    mask = _mask()
    result = refine_maps(photo, start, scene=Scene.flash(intensity=10.0), steps=5, backend="eager",
                         held=(mask, card))  # fmt: skip
    for name in ("normal", "diffuse", "roughness", "specular"):
        got, want = getattr(result.svbrdf, name), getattr(card, name)
        assert torch.equal(got[..., mask[0, 0]], want[..., mask[0, 0]]), name
        assert torch.isfinite(got).all()
    outside = ~mask[0, 0]
    assert not torch.equal(result.svbrdf.diffuse[..., outside], start.diffuse[..., outside])
    every = refine_maps(photo, start, scene=Scene.flash(intensity=10.0), steps=3, backend="eager",
                        held=(torch.ones(1, 1, 32, 32, dtype=torch.bool), card))  # fmt: skip
    assert torch.equal(every.svbrdf.diffuse, card.diffuse) and math.isfinite(float(every.losses[-1]))


def test_a_held_mask_of_the_wrong_shape_is_refused():
    photo = torch.rand(1, 3, 16, 16)
    with pytest.raises(MapError, match="held's mask"):
        refine_maps(photo, SVBRDF.constant(1, 16), steps=1, backend="eager",
                    held=(torch.ones(1, 1, 8, 8, dtype=torch.bool), card_maps(0.5, (16, 16))))  # fmt: skip


def test_the_flash_scene_carries_its_colour():
    scene = flash_scene(torch.tensor([[0.1, 0.0, 2.0]]), torch.tensor([3.0]), torch.tensor([[1.2, 1.0, 0.7]]))
    light = scene.point_lights[0]
    assert light.color.reshape(-1).tolist() == pytest.approx([1.2, 1.0, 0.7])
    assert float(light.intensity) == 3.0


def test_the_ring_penalty_does_not_see_a_held_card():
    """A dark, ring-free material with a bright card in a corner: counted, the card reads as a
    ring (and the penalty would brighten the material around it); excluded, the spread is 0,
    and its gradient finite."""
    from svbrdf_render.refinement.rings import RingBins, ring_penalty

    maps = SVBRDF.constant(1, 32, diffuse=(0.01, 0.01, 0.01))
    mask = _mask()
    card = card_maps(0.18, (32, 32))
    carded = SVBRDF(*(torch.where(mask, getattr(card, n), x) for n, x in maps.maps().items()), validate=False)
    point = torch.tensor([[0.0, 0.0]])
    assert float(ring_penalty(carded, RingBins(point, (1, 3, 32, 32)))) > 0.01
    diffuse = carded.diffuse.clone().requires_grad_(True)
    bins = RingBins(point, (1, 3, 32, 32), exclude=mask)
    spread = ring_penalty(SVBRDF(carded.normal, diffuse, carded.roughness, carded.specular, validate=False), bins)
    assert float(spread.detach()) == pytest.approx(0.0, abs=1e-6)
    spread.backward()
    assert torch.isfinite(diffuse.grad).all() and float(diffuse.grad[..., mask[0, 0]].abs().max()) == 0
