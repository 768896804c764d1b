"""Calibrated sets as MaterialGAN publishes them (``svbrdf-models predict --calibrated DIR``): their
units read into the project's, one material refined against the views used, the views left out
judged by relighting, and every bad set refused in one line before anything is written.

The sets are made here: known maps rendered by this project's renderer under five views chosen
in half-widths, written out in MaterialGAN's units (cm, power for a 1/d^2 in cm) and encoding
(a pure 2.2 gamma, plain 8-bit PNG)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from svbrdf_models.capture.calibrated import read_calibrated
from svbrdf_models.cli import main
from svbrdf_render import SVBRDF, Camera, PointLight, Scene, render
from svbrdf_render.examples import example_material

SIZE = 64
SIDE_CM = 10.0  # half a side: 5 cm
INTENSITY = 12.0  # in half-widths
#: Camera and flash together, in half-widths: views 0-2 refined against, 3 and 4 left out.
VIEWS = [(0.0, 0.0, 3.0), (1.5, 0.5, 3.0), (-1.2, 1.0, 2.8), (0.3, -1.5, 3.2), (-1.0, -1.0, 2.5)]


def _scene(p) -> Scene:
    return Scene(Camera(torch.tensor(p)), (PointLight(torch.tensor(p), INTENSITY),))


def _write_set(folder, photos: torch.Tensor, *, light_file: bool = True):
    """A MaterialGAN-style folder of ``photos`` (linear) under :data:`VIEWS`."""
    folder.mkdir(parents=True, exist_ok=True)
    half = SIDE_CM / 2
    for i, photo in enumerate(photos):
        encoded = photo.clamp(0, 1) ** (1 / 2.2)
        pixels = (encoded.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        Image.fromarray(pixels).save(folder / f"{i:02d}.png")
    lines = "".join(f"{x * half:.4f},{y * half:.4f},{z * half:.4f}\n" for x, y, z in VIEWS[: len(photos)])
    (folder / "camera_pos.txt").write_text(lines)
    if light_file:
        (folder / "light_pos.txt").write_text(lines)
    (folder / "image_size.txt").write_text(f"{SIDE_CM:.4f}\n")
    power = INTENSITY * half**2
    (folder / "light_power.txt").write_text(f"{power:.4f},{power:.4f},{power:.4f}\n")
    return folder


@pytest.fixture(scope="module")
def truth() -> SVBRDF:
    return example_material("leather", SIZE)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, truth):
    photos = torch.cat([render(truth, _scene(p)).clamp(0, 1) for p in VIEWS])
    return _write_set(tmp_path_factory.mktemp("sets") / "leather-set", photos)


def _run(*args, capsys):
    code = main(["predict", *map(str, args)])
    return code, capsys.readouterr()


# -- their units, read into the project's ---------------------------------------------------------


def test_the_set_is_read_in_half_widths_with_the_intensity_of_a_falloff_in_half_widths(calibrated):
    cal, photos = read_calibrated(calibrated)
    assert photos.shape == (5, 3, SIZE, SIZE) and cal.light_file == "light_pos.txt"
    assert torch.allclose(cal.camera, torch.tensor(VIEWS), atol=1e-3)
    assert torch.allclose(cal.light, torch.tensor(VIEWS), atol=1e-3)
    assert torch.allclose(cal.intensity, torch.full((5,), INTENSITY), rtol=1e-4)
    assert cal.frontal([1, 2]) == 1 and cal.frontal([1, 2, 3]) == 3 and cal.frontal([4, 0]) == 0


def test_a_scene_of_the_set_renders_what_materialgans_formula_gives_in_cm(calibrated):
    """Their Lambert term, in cm, at one pixel: albedo (1 - s) / pi * n.l / d_cm^2 * power, with
    pixel i at ((i + 0.5) / res - 0.5) * side and the row's y negated: the scene of view 1 gives it."""
    cal, _ = read_calibrated(calibrated)
    maps = SVBRDF.constant(1, 8, diffuse=(0.5, 0.4, 0.3), roughness=0.5, specular=(0.0,) * 3)
    scene = cal.scene(1).with_effects(("diffuse", "cosine", "falloff"))
    ours = render(maps, scene)[0]
    row, col = 2, 6
    p = torch.tensor([((col + 0.5) / 8 - 0.5) * SIDE_CM, -((row + 0.5) / 8 - 0.5) * SIDE_CM, 0.0])
    to_light = cal.light_cm[1] - p
    d2 = float(to_light.square().sum())
    cos = float(to_light[2]) / math.sqrt(d2)
    theirs = torch.tensor([0.5, 0.4, 0.3]) / math.pi * cos / d2 * cal.power[1]
    assert torch.allclose(ours[:, row, col], theirs, rtol=1e-4)


def test_a_set_without_light_positions_has_a_flash_at_each_camera(tmp_path, truth):
    photos = torch.cat([render(truth, _scene(p)).clamp(0, 1) for p in VIEWS[:2]])
    cal, _ = read_calibrated(_write_set(tmp_path / "flash", photos, light_file=False))
    assert cal.light_file == "camera_pos.txt" and torch.equal(cal.light_cm, cal.camera_cm)


# -- the command ------------------------------------------------------------------------------------


def _material(out, calibrated) -> dict:
    return json.loads((out / calibrated.name / "material.json").read_text())


def test_command_refines_against_the_views_used_and_judges_the_views_left_out(tmp_path, calibrated, capsys):
    out = tmp_path / "out"
    code, got = _run("--calibrated", calibrated, "--use", "0,1,2", "--holdout", "-o", out, "--refine", 60,
                     "--backend", "eager", "--relit", "none", capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    folder = out / calibrated.name
    assert str(folder) in got.out
    for name in ("normal.png", "diffuse.png", "roughness.png", "specular.png", "rerender.png", "input.png"):
        assert (folder / name).is_file(), name
    record = _material(out, calibrated)
    shots = record["shots"]
    assert [s["file"] for s in shots] == [f"{i:02d}.png" for i in range(5)]
    assert [s["used"] for s in shots] == [True, True, True, False, False]
    assert [s["held_out"] for s in shots] == [False, False, False, True, True]
    assert [s["gain"] for s in shots] == [1.0, 1.0, 1.0, None, None]  # fixed: the power is known
    assert shots[0]["network_view"] and not any(s["network_view"] for s in shots[1:])
    for s, view in zip(shots, VIEWS):
        assert s["camera"] == pytest.approx(list(view), abs=1e-3) and s["light"] == s["camera"]
        assert s["intensity"] == pytest.approx(INTENSITY, rel=1e-4)
        assert math.isfinite(s["rmse"]) and math.isfinite(s["rmse_network"])
    held = record["holdout"]
    assert held["views"] == ["03.png", "04.png"]
    assert math.isfinite(held["mean"]) and held["mean"] < held["mean_network"]  # refined relights better
    assert "holdout 03.png: relighting RMSE" in got.out and "holdout mean of 2 view(s)" in got.out
    assert record["refine"]["views"] == 3 and record["refine"]["steps"] == 60
    assert record["calibrated"]["side_cm"] == SIDE_CM and record["photo"]["encoding"] == "gamma 2.2"

    one = tmp_path / "one"
    code, got = _run("--calibrated", calibrated, "--use", "0", "--holdout", "-o", one, "--refine", 60,
                     "--backend", "eager", "--relit", "none", capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    alone = _material(one, calibrated)["holdout"]
    assert held["mean"] < alone["rmse"]["03.png"] / 2 + alone["rmse"]["04.png"] / 2  # three views beat one


def test_command_without_holdout_uses_every_view_and_says_none_was_left_out(tmp_path, truth, capsys):
    photos = torch.cat([render(truth, _scene(p)).clamp(0, 1) for p in VIEWS[:2]])
    folder = _write_set(tmp_path / "two", photos)
    code, got = _run("--calibrated", folder, "-o", tmp_path / "out", "--refine", 3, "--backend", "eager",
                     "--relit", "none", capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    record = _material(tmp_path / "out", folder)
    assert record["holdout"] is None and all(s["used"] for s in record["shots"])
    assert "relighting RMSE" not in got.out


# -- bad input: one line, exit 2, nothing written ---------------------------------------------------


def _spoil(folder, how: str) -> list[str]:
    """``folder`` spoilt as ``how`` says; the extra arguments of the command."""
    if how == "no camera_pos.txt":
        (folder / "camera_pos.txt").unlink()
    elif how == "no image_size.txt":
        (folder / "image_size.txt").unlink()
    elif how == "a photo missing":
        (folder / "01.png").rename(folder / "07.png")
    elif how == "fewer positions than photos":
        lines = (folder / "camera_pos.txt").read_text().splitlines()
        (folder / "camera_pos.txt").write_text("\n".join(lines[:-1]) + "\n")
    elif how == "two powers for three photos":
        (folder / "light_power.txt").write_text("300,300,300\n300,300,300\n")
    elif how == "a word in light_pos.txt":
        (folder / "light_pos.txt").write_text("0,0,15\nabc,def,ghi\n0,1,15\n")
    return {"--use out of range": ["--use", "0,3"], "--use repeated": ["--use", "0,1,0"],
            "--use everything with --holdout": ["--use", "2,1,0", "--holdout"],
            "--holdout with every view by default": ["--holdout"]}.get(how, [])  # fmt: skip


BAD = {
    "no camera_pos.txt": "no camera_pos.txt",
    "no image_size.txt": "no image_size.txt",
    "a photo missing": "no 01.png but 07.png",
    "fewer positions than photos": "3 photos but 2 camera positions",
    "two powers for three photos": "3 photos but 2 light powers",
    "a word in light_pos.txt": "line 2 'abc,def,ghi' is not 3 number(s)",
    "--use out of range": "--use 3: the set has views 0 to 2",
    "--use repeated": "--use names view 0 twice",
    "--use everything with --holdout": "no view is left to judge",
    "--holdout with every view by default": "no view is left to judge",
}


@pytest.mark.parametrize("how", list(BAD))
def test_a_bad_set_or_view_list_is_refused_in_one_line_with_nothing_written(tmp_path, truth, how, capsys):
    photos = torch.cat([render(truth, _scene(p)).clamp(0, 1) for p in VIEWS[:3]])
    folder = _write_set(tmp_path / "set", photos[:, :, :16, :16].contiguous())
    extra = _spoil(folder, how)
    out = tmp_path / "out"
    code, got = _run("--calibrated", folder, "-o", out, "--refine", 2, *extra, capsys=capsys)
    assert code == 2
    lines = got.err.strip().splitlines()
    assert len(lines) == 1 and BAD[how] in lines[0], got.err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    "args, says",
    [
        (["-o", "out"], "no photos: give the photos to capture (PHOTO ...) or --calibrated DIR"),
        (["a.png", "--calibrated", "set", "-o", "out"], "give photos or --calibrated DIR, not both"),
        (["a.png", "--use", "0", "-o", "out"], "--use goes with --calibrated DIR"),
        (["a.png", "--holdout", "-o", "out"], "--holdout goes with --calibrated DIR"),
        (["--calibrated", "set", "--use", "0,x", "-o", "out"], "expected view numbers"),
        (["--calibrated", "set", "--tiles", "-o", "out"], "--calibrated with --tiles"),
        (["--calibrated", "no-such-set", "-o", "out"], "no-such-set: no such folder"),
    ],
)
def test_photos_or_a_calibrated_set_one_of_them(tmp_path, monkeypatch, args, says, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "set").mkdir()
    code, got = _run(*args, capsys=capsys)
    assert code == 2 and says in got.err and len(got.err.strip().splitlines()) == 1, got.err
