"""A grey card in the photo measures the flash (issue 44, part 1): its intensity and colour read
off the card's pixels through the renderer's own image formation, the network's diffuse brought
to the level that flash implies, the refinement run under it with the card held, and the
highlight finder blind to the card. A bad card (clipped, dark, implausible, of no albedo) is
one line and exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from svbrdf_models.capture.reference import Reference, pin_flash, reference_mask
from svbrdf_models.cli import main
from svbrdf_render import SVBRDF, Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.refinement.fit import card_maps, flash_scene, reference_flash
from svbrdf_render.refinement.rings import highlight_point

LUMA = torch.tensor([0.2126, 0.7152, 0.0722]).view(1, 3, 1, 1)


def _with_card(maps: SVBRDF, box, albedo: float = 0.18) -> SVBRDF:
    """``maps`` with a matte card of ``albedo`` over ``box`` = (top, left, bottom, right) px."""
    t, l, b, r = box
    card = card_maps(albedo, maps.size, maps.batch_size)
    mask = torch.zeros(1, 1, *maps.size, dtype=torch.bool)
    mask[..., t:b, l:r] = True
    return SVBRDF(*(torch.where(mask, getattr(card, n), x) for n, x in maps.maps().items()), validate=False)


@pytest.mark.parametrize("position", [(0.0, 0.0, 2.2), (0.3, -0.2, 3.0), (-0.5, 0.4, 1.8)])
def test_the_card_gives_the_flash_intensity_and_colour(position):
    """Wherever the card lies in the field of view (here a corner, where the fall-off and the
    cosine dim it most), the flash it gives is the one the photo was taken under."""
    maps = _with_card(example_material("tiles", 96), (4, 4, 28, 28))
    pos = torch.tensor([position])
    color = torch.tensor([[1.1, 1.0, 0.8]])
    photo = render(maps, flash_scene(pos, torch.tensor([9.0]), color))
    mask = torch.zeros(1, 1, 96, 96, dtype=torch.bool)
    mask[..., 6:26, 6:26] = True
    got = reference_flash(photo.clamp(0, 1), mask, 0.18, pos)
    truth = 9.0 * float((color * LUMA.view(1, 3)).sum())
    assert float(got.intensity[0]) == pytest.approx(truth, rel=0.02)
    assert got.color[0] / got.color[0, 1] == pytest.approx(color[0] / color[0, 1], rel=0.02)
    assert float(got.clipped[0]) == 0 and int(got.pixels[0]) == 400


def test_the_highlight_finder_ignores_the_card():
    """A white card in a corner is the brightest thing of the blurred photo: ignored, the
    highlight is found where the flash is."""
    flat = torch.zeros(1, 3, 96, 96)
    flat[:, 2] = 1
    dark = SVBRDF(flat, torch.full_like(flat, 0.04), torch.full((1, 1, 96, 96), 0.4), torch.full_like(flat, 0.04))
    maps = _with_card(dark, (0, 0, 30, 30), albedo=0.9)  # a dark, fairly rough material; a white card
    photo = render(maps, flash_scene(torch.tensor([[0.2, -0.2, 2.2]]), torch.tensor([12.0]))).clamp(0, 1)
    mask = torch.zeros(1, 1, 96, 96, dtype=torch.bool)
    mask[..., 0:30, 0:30] = True
    fooled = highlight_point(photo)[0]
    found = highlight_point(photo, ignore=mask)[0]
    assert fooled[0] < -0.5 and fooled[1] > 0.5  # the card's corner, without the mask
    assert found.tolist() == pytest.approx([0.2, -0.2], abs=0.1)


def _photo(path: Path, exposure: float, size: int = 96, card=(4, 4, 28, 28), albedo=0.18) -> tuple[Path, SVBRDF]:
    maps = _with_card(example_material("tiles", size), card, albedo)
    photo = render(maps, Scene.flash(intensity=12.0 * exposure)).clamp(0, 1)[0]
    return write_image(path, linear_to_srgb(photo)), maps


def _level(diffuse: torch.Tensor) -> float:
    """Mean luminance of the material's part of a diffuse map (the card is in the top left)."""
    return float((diffuse[..., 40:96, 40:96] * LUMA).sum(1).mean())


def test_a_card_measures_the_flash_and_sets_the_albedo_level(tmp_path):
    """Half or twice the exposure, the camera's distance known (``--distance``): the flash
    measured follows the exposure, the material's refined diffuse is the same at both (where
    without the card it follows the exposure) and as near the truth as the refinement under the
    true flash gets, and the card's pixels hold the card."""
    from svbrdf_models import load_model
    from svbrdf_models.capture.refining import refine_prediction
    from svbrdf_render import read_image, srgb_to_linear

    levels, default = [], []
    for exposure in (0.5, 2.0):
        photo, truth = _photo(tmp_path / f"card{exposure}.png", exposure)
        out = tmp_path / f"out{exposure}"
        args = ["--refine", "30", "--relit", "none", "--threads", "1", "--distance", "2.2",
                "--reference", "4,4,24,24:0.18"]  # fmt: skip
        assert main(["predict", str(photo), "-o", str(out), *args]) == 0
        folder = out / f"card{exposure}"
        record = json.loads((folder / "material.json").read_text())["reference"]
        assert record["flash_intensity"] == pytest.approx(12.0 * exposure, rel=0.03)
        assert record["region"] == [4, 4, 24, 24] and record["albedo"] == 0.18
        diffuse = srgb_to_linear(read_image(folder / "diffuse.png"))[None]
        levels.append(_level(diffuse))
        assert float((diffuse[..., 8:24, 8:24] * LUMA).sum(1).mean()) == pytest.approx(0.18 / 0.96, rel=0.02)
        # the same refinement under the true flash, and under the flash guessed without the card
        square = render(truth, Scene.flash(intensity=12.0 * exposure)).clamp(0, 1)
        model = load_model("pretrained")
        net = model.predict(square[0])
        known = refine_prediction(square, net, 30, scene=Scene.flash(intensity=12.0 * exposure), backend="eager")
        want = _level(truth.diffuse)
        assert abs(levels[-1] - want) <= 1.1 * abs(_level(known.svbrdf.diffuse) - want)  # as close as that
        default.append(_level(refine_prediction(square, net, 30, backend="eager").svbrdf.diffuse))
    assert levels[0] == pytest.approx(levels[1], rel=0.1)
    assert max(default) / min(default) > 1.5  # what the card saves: the level followed the exposure


def test_without_geometry_the_flash_stands_over_the_highlight(tmp_path):
    """No EXIF, no --distance: the camera and flash are guessed over the photo's highlight at
    the Des18 distance, as without a card; on this textured photo the guess is 0.2 half-widths
    off, and the intensity read off a corner card within 10%."""
    photo, _ = _photo(tmp_path / "card.png", 1.0)
    out = tmp_path / "out"
    args = ["--refine", "0", "--relit", "none", "--reference", "4,4,24,24:0.18"]
    assert main(["predict", str(photo), "-o", str(out), *args]) == 0
    record = json.loads((out / "card" / "material.json").read_text())["reference"]
    assert record["flash_position"][2] == pytest.approx(2.2)
    assert record["flash_intensity"] == pytest.approx(12.0, rel=0.1)


def test_pin_flash_puts_the_camera_where_it_is_told():
    maps = _with_card(example_material("tiles", 64), (0, 0, 16, 16), albedo=0.5)
    photo = render(maps, Scene.flash(intensity=10.0)).clamp(0, 1)[0]
    ref = Reference.parse("0,0,16,16:0.5")
    pinned = pin_flash(photo, example_material("tiles", 64), ref, (0, 0, 64, 64, 64), "x.png",
                       position=torch.tensor([0.1, 0.2, 3.0]))  # fmt: skip
    assert pinned.record["flash_position"] == pytest.approx([0.1, 0.2, 3.0])
    assert reference_mask(ref, (0, 0, 64, 64, 64), 32, "x").sum() == 64


def test_with_the_lens_known_the_card_s_reading_allows_for_the_tilted_view():
    """``focal`` given: the phone at ``position``, off the axis, is aimed at the square's centre,
    and the flash read off a card on the far side is raised by the perspective's factor
    (recorded as ``tilt_factor``); without it, nothing changes."""
    from svbrdf_render.refinement.falloff import tilted_view_factor

    maps = _with_card(example_material("tiles", 64), (0, 0, 16, 16), albedo=0.5)
    photo = render(maps, Scene.flash(intensity=10.0)).clamp(0, 1)[0]
    ref, box, at = Reference.parse("0,0,16,16:0.5"), (0, 0, 64, 64, 64), torch.tensor([0.6, -0.5, 2.0])
    plain = pin_flash(photo, example_material("tiles", 64), ref, box, "x.png", position=at)
    tilted = pin_flash(photo, example_material("tiles", 64), ref, box, "x.png", position=at, focal=2.2)
    factor = tilted_view_factor(reference_mask(ref, box, 64, "x"), at, 2.2)
    assert factor > 1.05  # the card in the top-left corner, the phone at the bottom right
    assert tilted.record["tilt_factor"] == pytest.approx(factor, abs=1e-4) and plain.record["tilt_factor"] == 1.0
    assert tilted.record["flash_intensity"] == pytest.approx(plain.record["flash_intensity"] * factor, rel=1e-5)
    assert float(tilted.scene.point_lights[0].intensity.reshape(-1)[0]) == pytest.approx(
        tilted.record["flash_intensity"], rel=1e-5)


@pytest.mark.parametrize(
    ("exposure", "card", "spec", "needle"),
    [
        (40.0, 0.18, "4,4,24,24:0.18", "clipped"),
        (0.01, 0.18, "4,4,24,24:0.18", "too dark to read"),
        (1.0, 0.18, "4,4,24,24:0.001", "albedo must be in"),
        (1.0, 0.18, "4,4,24,24:1e-300", "albedo must be in"),
        (1.0, 0.03, "4,4,24,24:0.8", "times brighter"),  # a dark card said to be white paper
    ],
)
def test_a_bad_card_is_one_line_and_exit_2(tmp_path, capsys, exposure, card, spec, needle):
    photo, _ = _photo(tmp_path / "card.png", exposure, albedo=card)
    out = tmp_path / "o"
    code = main(["predict", str(photo), "-o", str(out), "--refine", "0", "--relit", "none", "--reference", spec])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err
    assert not (out / "card").exists()


def test_a_card_and_a_scene_are_refused_together(tmp_path, capsys):
    from svbrdf_models.capture.one import CaptureOptions
    from svbrdf_models.errors import DataError

    with pytest.raises(DataError, match="give one"):
        CaptureOptions(refine=10, scene=Scene.flash(), reference=Reference.parse("0,0,8,8:0.18"))


def test_the_python_api_takes_a_reference(tmp_path):
    """``predict(photo, refine=..., reference=...)``: the same measured flash as the command
    line; the card's pixels held at the card; one photo only, not with a scene."""
    from svbrdf_models import load_model
    from svbrdf_models.errors import DataError

    maps = _with_card(example_material("tiles", 96), (4, 4, 28, 28))
    photo = render(maps, Scene.flash(intensity=6.0)).clamp(0, 1)[0]
    model = load_model("pretrained")
    plain = model.predict(photo, refine=10)
    pinned = model.predict(photo, refine=10, reference="4,4,24,24:0.18")
    assert pinned.size == (96, 96)
    card = float((pinned.diffuse[..., 8:24, 8:24] * LUMA).sum(1).mean())
    assert card == pytest.approx(0.18 / 0.96, rel=0.01)
    assert _level(pinned.diffuse) > 1.3 * _level(plain.diffuse)  # the dim exposure no longer darkens it
    assert model.predict(photo, reference=Reference.parse("4,4,24,24:0.18")).size == (128, 128)
    with pytest.raises(DataError, match="one photo"):
        model.predict(torch.stack([photo, photo]), reference="4,4,24,24:0.18")
    with pytest.raises(DataError, match="give one"):
        model.predict(photo, refine=5, scene=Scene.flash(), reference="4,4,24,24:0.18")


def test_the_network_is_shown_the_material_where_the_card_is():
    """The card's square is filled from the material around it before the network sees the
    photo: known pixels untouched, the fill within the range of its surroundings, finite for a
    region on the border and for a region that is the whole photo."""
    from svbrdf_models.capture.reference import fill_card

    photo = render(example_material("tiles", 64), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    carded = photo.clone()
    carded[:, 0:20, 0:20] = 1.0  # a white card in the corner
    mask = torch.zeros(1, 1, 64, 64, dtype=torch.bool)
    mask[..., 0:20, 0:20] = True
    filled = fill_card(carded, mask)
    assert torch.equal(filled[:, ~mask[0, 0]], carded[:, ~mask[0, 0]])
    region = filled[:, 0:20, 0:20]
    assert torch.isfinite(region).all() and float(region.max()) < 0.95  # no white card left
    around = photo[:, 0:28, 0:28]
    assert float(region.mean()) == pytest.approx(float(around.mean()), rel=0.5)
    everything = torch.ones(1, 1, 64, 64, dtype=torch.bool)
    assert torch.equal(fill_card(carded, everything), carded)
    assert fill_card(carded, torch.zeros(1, 1, 32, 32, dtype=torch.bool)).shape == carded.shape  # another size
