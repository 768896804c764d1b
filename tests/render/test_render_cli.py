"""The svbrdf-render command: renders, previews, templates, and clear errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from conftest import random_svbrdf
from svbrdf_render import Scene, write_des18, write_map_folder
from svbrdf_render.cli import main


def _load(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im)


def _run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_render_an_example_to_png(tmp_path, capsys):
    out = tmp_path / "tiles.png"
    code, stdout, _ = _run(capsys, "render", "example:tiles", "-o", str(out), "--size", "32", "--gamma", "2.2")
    assert code == 0 and "wrote" in stdout
    arr = _load(out)
    assert arr.shape == (32, 32, 3) and arr.std() > 5  # a picture, not a flat fill


def test_render_a_des18_strip_and_a_map_folder(tmp_path, capsys):
    import torch

    m = random_svbrdf(1, 16)
    write_des18(tmp_path / "s.png", torch.rand(3, 16, 16), m)
    write_map_folder(tmp_path / "maps", m)
    for src in (tmp_path / "s.png", tmp_path / "maps"):
        out = tmp_path / f"{src.stem}-out.png"
        code, _, _ = _run(capsys, "render", str(src), "-o", str(out), "--light", "0.5", "0.5", "2", "--bits", "16")
        assert code == 0
        assert _load(out).shape[:2] == (16, 16)
    a = _load(tmp_path / "s-out.png")
    b = _load(tmp_path / "maps-out.png")
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 2 * 257  # same maps, 8-bit stored


def test_preview_grid(tmp_path, capsys):
    out = tmp_path / "grid.png"
    code, _, _ = _run(capsys, "preview", "example:leather", "-o", str(out), "--grid", "2", "--size", "16")
    assert code == 0
    arr = _load(out).astype(float)
    assert arr.shape == (32, 32, 3)
    # Different light positions give different tiles.
    assert np.abs(arr[:16, :16] - arr[16:, 16:]).mean() > 1


def test_scene_template_round_trips_through_render(tmp_path, capsys):
    yml = tmp_path / "scene.yaml"
    assert _run(capsys, "scene", "-o", str(yml))[0] == 0
    Scene.load(yml)
    code, _, _ = _run(capsys, "render", "example:tiles", "--size", "16", "--scene", str(yml), "-o", str(tmp_path / "a.png"))
    assert code == 0


def test_effects_listing(capsys):
    code, out, _ = _run(capsys, "effects")
    assert code == 0 and "vignetting" in out and "alpha_floor" in out


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["render", "missing.png", "-o", "x.png"], "no such file or folder"),
        (["render", "example:marble", "-o", "x.png"], "unknown example 'marble'"),
        (["preview", "example:tiles", "-o", "x.png", "--grid", "0"], "--grid: expected an integer from 1 to 16, got 0"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, fragment, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, *args)
    assert code == 2
    assert fragment in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def test_bad_files_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    code, _, err = _run(capsys, "render", str(bad), "-o", str(tmp_path / "o.png"))
    assert code == 2 and "bad.png" in err
    yml = tmp_path / "s.yaml"
    yml.write_text("effects: [difuse]")
    code, _, err = _run(capsys, "render", "example:tiles", "--scene", str(yml), "-o", str(tmp_path / "o.png"))
    assert code == 2 and "did you mean 'diffuse'" in err


def test_console_script_help_and_usage_error():
    exe = [sys.executable, "-m", "svbrdf_render.cli"]
    r = subprocess.run([*exe, "render", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "examples:" in r.stdout
    r = subprocess.run([*exe, "render", "example:tiles"], capture_output=True, text=True)
    assert r.returncode == 2 and "-o/--output" in r.stderr


# -- every flag: out-of-range values and combinations that would be ignored ------------------

SCENE_YAML = "camera: {position: [0, 0, 2.2]}\nlights: [{type: flash, intensity: 15}]\n"


@pytest.mark.parametrize(
    "args, fragments",
    [
        # --distance 0 was a ZeroDivisionError, --size -3 a traceback, --size 100000 an 80 GB allocation
        (["render", "example:tiles", "--distance", "0"], ["--distance", "> 0", "got 0"]),
        (["render", "example:tiles", "--distance", "-2"], ["--distance", "got -2"]),
        (["render", "example:tiles", "--distance", "inf"], ["--distance", "finite", "got inf"]),
        (["render", "example:tiles", "--size", "-3"], ["--size", "from 1 to 8192", "got -3"]),
        (["render", "example:tiles", "--size", "100000"], ["--size", "from 1 to 8192", "got 100000"]),
        (["render", "example:tiles", "--size", "0"], ["--size", "got 0"]),
        (["render", "example:tiles", "--size", "1.5"], ["--size", "expected an integer, got '1.5'"]),
        (["render", "example:tiles", "--intensity", "-1"], ["--intensity", ">= 0", "got -1"]),
        (["render", "example:tiles", "--intensity", "nan"], ["--intensity", "got nan"]),
        (["render", "example:tiles", "--light", "0", "0", "-1"], ["--light 0 0 -1", "Z must be > 0"]),
        (["render", "example:tiles", "--light", "0", "0", "0"], ["--light 0 0 0", "Z must be > 0"]),
        (["render", "example:tiles", "--light", "nan", "0", "1"], ["--light", "got nan"]),
        (["render", "example:tiles", "--exposure", "1000"], ["--exposure", "<= 64", "got 1000"]),
        (["render", "example:tiles", "--exposure=-inf"], ["--exposure", "got -inf"]),
        (["render", "example:tiles", "--gamma", "0"], ["--gamma", "> 0", "got 0"]),
        (["render", "example:tiles", "--gamma", "-2.2"], ["--gamma", "got -2.2"]),
        (["render", "example:tiles", "--bits", "12"], ["--bits", "12"]),
        (["render", "example:tiles", "--backend", "fast"], ["--backend", "'fast'"]),
        (["render", "example:tiles", "--effects", "difuse"], ["--effects", "'difuse'"]),
        # with --scene the file sets camera, lights and effects: these flags would be ignored
        (["render", "example:tiles", "--scene", "SCENE", "--distance", "3"], ["--distance with --scene", "scene.yaml"]),
        (["render", "example:tiles", "--scene", "SCENE", "--intensity", "5"], ["--intensity with --scene"]),
        (["render", "example:tiles", "--scene", "SCENE", "--light", "0", "0", "2"], ["--light with --scene"]),
        (["render", "example:tiles", "--scene", "SCENE", "--effects", "diffuse"], ["--effects with --scene"]),
        (["preview", "example:tiles", "--scene", "SCENE", "--distance", "3", "--intensity", "2"], ["--distance, --intensity with --scene"]),
        (["preview", "example:tiles", "--grid", "17"], ["--grid", "from 1 to 16", "got 17"]),
        (["preview", "example:tiles", "--grid", "-1"], ["--grid", "got -1"]),
        (["preview", "example:tiles", "--spread", "-1"], ["--spread", ">= 0", "got -1"]),
        (["preview", "example:tiles", "--height", "0"], ["--height", "> 0", "got 0"]),
        (["preview", "example:tiles", "--height", "nan"], ["--height", "got nan"]),
        (["preview", "example:tiles", "--size", "100000"], ["--size", "8192", "got 100000"]),
        (["preview", "example:tiles", "--grid", "16", "--size", "1024"], ["--grid 16 x --size 1024", "16384 px", "8192"]),
        # preview moves the light over its grid: a --light would be ignored
        (["preview", "example:tiles", "--light", "0", "0", "1"], ["--light 0 0 1", "preview moves the light"]),
    ],
)
def test_bad_flag_values_are_refused_before_any_work(args, fragments, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_text(SCENE_YAML)
    args = [str(tmp_path / "scene.yaml") if a == "SCENE" else a for a in args]
    code, out, err = _run(capsys, *args, "-o", "x.png")
    assert code == 2, (args, err)
    assert "Traceback" not in err and err.startswith("svbrdf-render") and err.count("\n") == 1, err
    for fragment in fragments:
        assert fragment in err, (fragment, err)
    assert not (tmp_path / "x.png").exists() and out == ""


def test_preview_refuses_a_scene_with_several_lights(tmp_path, capsys):
    # Only one light moves over the grid: the others would have been dropped without a word.
    yml = tmp_path / "two.yaml"
    yml.write_text("lights: [{type: flash, intensity: 5}, {type: point, position: [1, 1, 2]}]\n")
    code, _, err = _run(capsys, "preview", "example:tiles", "--scene", str(yml), "-o", str(tmp_path / "g.png"))
    assert code == 2 and "two.yaml" in err and "2 light(s)" in err and err.count("\n") == 1
    assert not (tmp_path / "g.png").exists()


def test_preview_refuses_a_grid_of_large_maps_before_rendering(tmp_path, capsys):
    # Without --size the maps keep their own size: 14 x 600 px would be an 8400 px grid.
    write_map_folder(tmp_path / "big", random_svbrdf(1, 600))
    code, _, err = _run(capsys, "preview", str(tmp_path / "big"), "--grid", "14", "-o", str(tmp_path / "h.png"))
    assert code == 2 and "600 px maps on a --grid 14 make a 8400 px grid" in err and err.count("\n") == 1
    assert not (tmp_path / "h.png").exists()
    code, _, err = _run(capsys, "preview", str(tmp_path / "big"), "--grid", "14", "--size", "8", "-o", str(tmp_path / "h.png"))
    assert code == 0 and _load(tmp_path / "h.png").shape[:2] == (112, 112)


def test_flags_that_do_work_with_a_scene_and_a_preview(tmp_path, capsys):
    yml = tmp_path / "scene.yaml"
    yml.write_text(SCENE_YAML)
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert _run(capsys, "render", "example:tiles", "--size", "16", "--scene", str(yml), "-o", str(a))[0] == 0
    code, _, _ = _run(capsys, "render", "example:tiles", "--size", "16", "--scene", str(yml), "--exposure", "1", "-o", str(b))
    assert code == 0 and _load(b).astype(int).sum() > _load(a).astype(int).sum()  # brighter by a stop
    assert _run(capsys, "preview", "example:tiles", "--size", "8", "--grid", "2", "--distance", "3", "-o", str(a))[0] == 0
