"""The material folder's viewer starts with its light where the photo's flash was, and a
capture that records shots gives the viewer each shot's flash (keys 1-9)."""

from __future__ import annotations

import json
import re

import pytest

from svbrdf_models.capture.material import _shot_lights
from svbrdf_models.cli import main
from svbrdf_render import Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb


def _page_data(page) -> dict:
    text = page.read_text()
    return json.loads(re.search(r'<script type="application/json" id="svbrdf-data">(.*?)</script>', text, re.S).group(1))


def test_the_viewer_starts_where_the_photo_s_flash_was(tmp_path):
    photo = render(example_material("tiles", 64), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    path = write_image(tmp_path / "tiles.png", linear_to_srgb(photo))
    assert main(["predict", str(path), "-o", str(tmp_path / "out"), "--refine", "0", "--relit", "none"]) == 0
    folder = tmp_path / "out" / "tiles"
    flash = json.loads((folder / "material.json").read_text())["flash"]["position"]
    assert flash[2] > 0
    assert _page_data(folder / "index.html")["light"] == pytest.approx(flash)


def test_recorded_shots_become_the_viewer_s_keys():
    record = {"shots": [
        {"file": "a.jpg", "light": [0.1, 0.0, 2.0]},
        {"file": "b.jpg", "light": [0.0, 0.0, -1.0]},  # below the patch: left out
        {"light": [0.2, 0.2, 3.0]},
        "junk",
    ]}  # fmt: skip
    assert _shot_lights(record) == [("a.jpg", [0.1, 0.0, 2.0]), ("shot 3", [0.2, 0.2, 3.0])]
    assert _shot_lights({}) == []
