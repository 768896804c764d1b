"""Where the capture took the flash to be (issue 47): ``predict`` says in one line whether it
stood over the photo's highlight or was assumed over the centre, material.json records it
(``flash.placed``, ``flash.highlight``), and a highlight near the edge of the captured square
gets a note with what docs/capture-guide.md measured it to cost."""

from __future__ import annotations

import json
import re

import pytest
import torch

from conftest import REPO
from svbrdf_models.capture.geometry import EDGE, EDGE_COST, PLACES, edge_note, flash_line
from svbrdf_models.cli import main
from svbrdf_render import SVBRDF, render, write_image
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.refinement.fit import flash_scene


def _glossy(tmp_path, x: float, y: float, name: str = "glossy"):
    """An sRGB flash photo of a glossy grey material, the flash over ``(x, y)``."""
    maps = SVBRDF.constant(1, 64, diffuse=(0.2, 0.2, 0.2), roughness=0.3, specular=(0.04, 0.04, 0.04))
    photo = render(maps, flash_scene(torch.tensor([[x, y, 2.2]]), torch.tensor([10.0]))).clamp(0, 1)[0]
    return write_image(tmp_path / f"{name}.png", linear_to_srgb(photo))


def _flat(tmp_path):
    """A photo with no highlight at all: the same grey everywhere."""
    return write_image(tmp_path / "flat.png", torch.full((3, 64, 64), 0.4))


def _capture(tmp_path, path, capsys, *flags):
    out = tmp_path / "out"
    assert main(["predict", str(path), "-o", str(out), "--relit", "none", *flags]) == 0
    err = capsys.readouterr().err
    return json.loads((out / path.stem / "material.json").read_text())["flash"], err


def test_a_clear_highlight_is_where_the_flash_stood_and_it_is_said(tmp_path, capsys):
    flash, err = _capture(tmp_path, _glossy(tmp_path, 0.2, 0.1), capsys, "--refine", "2")
    assert flash["placed"] == "highlight" and flash["highlight"]["found"] is True
    x, y = flash["highlight"]["point"]
    assert (x, y) == pytest.approx((0.2, 0.1), abs=0.1)
    assert flash["position"][:2] == pytest.approx([x, y], abs=1e-3)  # the refinement stood there
    assert flash["highlight"]["off_centre"] == pytest.approx((x * x + y * y) ** 0.5, abs=1e-3)
    lines = [line for line in err.splitlines() if "flash taken over its highlight found at" in line]
    assert len(lines) == 1 and "glossy.png" in lines[0], err
    assert "near its edge" not in err


def test_no_clear_highlight_is_said_to_be_assumed_at_the_centre(tmp_path, capsys):
    flash, err = _capture(tmp_path, _flat(tmp_path), capsys, "--refine", "2")
    assert flash["placed"] == "centre"
    assert flash["highlight"] == {"found": False, "point": None, "off_centre": None}
    assert flash["position"][:2] == pytest.approx([0.0, 0.0])
    assert "no clear highlight in the photo: the flash assumed over the centre of the square" in err, err


def test_a_highlight_near_the_edge_is_warned_with_what_it_costs(tmp_path, capsys):
    flash, err = _capture(tmp_path, _glossy(tmp_path, 0.75, 0.1, "edge"), capsys, "--refine", "2")
    assert flash["highlight"]["off_centre"] >= EDGE
    notes = [line for line in err.splitlines() if "near its edge" in line]
    assert len(notes) == 1 and notes[0].startswith("svbrdf-models: note: ") and "edge.png" in notes[0], err
    assert EDGE_COST in notes[0] and "docs/capture-guide.md" in notes[0]


def test_without_refinement_the_highlight_is_recorded_and_the_flash_fitted(tmp_path, capsys):
    flash, err = _capture(tmp_path, _glossy(tmp_path, 0.75, 0.1, "edge"), capsys, "--refine", "0")
    assert flash["placed"] == "fitted" and flash["highlight"]["found"] is True
    assert "flash fitted to the network's maps" in err and "near its edge" in err


def test_the_warning_quotes_the_docs_off_centre_row():
    """EDGE and EDGE_COST are docs/capture-guide.md's off-centre row: its offset, its diffuse and
    render columns."""
    guide = (REPO / "docs" / "capture-guide.md").read_text()
    row = next(line for line in guide.splitlines() if line.startswith("| off-centre"))
    assert f"{EDGE:g} half-widths" in row
    cells = [c.strip() for c in row.strip("|").split("|")]
    diffuse, render_ = re.search(r"\(([+-]\d+%)\)", cells[2])[1], re.search(r"\(([+-]\d+%)\)", cells[5])[1]
    assert EDGE_COST == f"diffuse {diffuse}, re-rendering {render_}"


@pytest.mark.parametrize("placed", sorted(PLACES))
def test_every_placement_has_its_line(placed):
    found = {"placed": placed, "position": [0.1, 0.2, 2.2],
             "highlight": {"found": True, "point": [0.7, 0.1], "off_centre": 0.7071}}  # fmt: skip
    none = {**found, "highlight": {"found": False, "point": None, "off_centre": None}}
    assert "\n" not in flash_line(found) and "\n" not in flash_line(none)
    assert ("x +0.70, y +0.10" in flash_line(found)) and "no clear highlight" in flash_line(none)
    if placed == "fall-off":  # where it stood, 0.22 from the centre: no note, highlight or not
        assert "x +0.10, y +0.20" in flash_line(found) and edge_note(found) is None
        far = {**none, "position": [0.7, -0.1, 2.0]}
        assert "flash stood 0.71 half-widths" in edge_note(far) and "a square under the flash" in edge_note(far)
    else:
        assert edge_note(found) is not None and edge_note(none) is None
