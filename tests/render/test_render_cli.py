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
        (["preview", "example:tiles", "-o", "x.png", "--grid", "0"], "--grid must be"),
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
