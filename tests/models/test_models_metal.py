"""``--metal auto|none`` (issue 47): a user can say "this is not a metal". Black glossy plastic,
a dark diffuse under a bright highlight, reads as metal to the network and to the metal/rough
conversion (metallic 0.99); with ``none`` the specular albedo is the grey 0.04 of a dielectric
everywhere, metallic.png is 0, the refinement runs with the specular held there (and still
lowers its loss), and material.json says so. ``auto`` is the capture as it was."""

from __future__ import annotations

import json

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models.capture.one import CaptureOptions, capture_one
from svbrdf_models.capture.refining import refine_prediction
from svbrdf_models.cli import main
from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, read_image, render, write_image
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.refinement.fit import flash_scene


def _plastic(size: int = 64) -> SVBRDF:
    """Black glossy plastic: a dark diffuse, a dielectric's 0.04, a tight highlight."""
    return SVBRDF.constant(1, size, diffuse=(0.02, 0.02, 0.025), roughness=0.25, specular=(0.04, 0.04, 0.04))


def _photo(tmp_path, size: int = 64):
    """An sRGB flash photo of the plastic, the flash a little off the centre."""
    scene = flash_scene(torch.tensor([[0.1, -0.05, 2.2]]), torch.tensor([10.0]))
    photo = render(_plastic(size), scene).clamp(0, 1)[0]
    return write_image(tmp_path / "plastic.png", linear_to_srgb(photo))


class _Chrome:
    """A network that calls the plastic a metal: the dark diffuse, a bright grey specular."""

    resolution = 64
    source, sha256, steps = "known:chrome", "0" * 64, 0

    def predict(self, photo):
        return SVBRDF.constant(1, 64, diffuse=(0.02, 0.02, 0.02), roughness=0.3, specular=(0.6, 0.6, 0.6))


def _read(folder, name):
    return read_image(folder / name, channels=None)


@pytest.mark.parametrize("refine", [0, 6])
def test_metal_none_writes_a_dielectric_and_says_so(tmp_path, refine):
    path = _photo(tmp_path)
    options = dict(refine=refine, relit="none", bits=16, albedo_encoding="linear")
    capture_one(_Chrome(), path, tmp_path / "auto", CaptureOptions(**options))
    capture_one(_Chrome(), path, tmp_path / "none", CaptureOptions(**options, metal="none"))
    assert float(_read(tmp_path / "auto", "metallic.png").max()) > 0.9  # what the conversion says of it
    metallic, specular = _read(tmp_path / "none", "metallic.png"), _read(tmp_path / "none", "specular.png")
    assert float(metallic.abs().max()) == 0.0
    assert torch.allclose(specular, torch.full_like(specular, 0.04), atol=1 / 65535)
    for name, metal in (("auto", "auto"), ("none", "none")):
        assert json.loads((tmp_path / name / "material.json").read_text())["metal"] == metal


def test_the_refinement_under_metal_none_holds_the_specular_and_lowers_its_loss(tmp_path):
    photo = render(_plastic(), flash_scene(torch.tensor([[0.1, -0.05, 2.2]]), torch.tensor([10.0]))).clamp(0, 1)
    result = refine_prediction(photo, _Chrome().predict(None), 30, backend="eager", metal="none")
    assert torch.equal(result.svbrdf.specular, torch.full_like(result.svbrdf.specular, 0.04))
    assert float(result.losses[-1]) < float(result.losses[0])
    start = _Chrome().predict(None)
    assert not torch.allclose(result.svbrdf.roughness, start.roughness.expand_as(result.svbrdf.roughness))


def test_metal_auto_is_the_capture_as_it_was(tmp_path, refine_calls):
    """The capture's refinement with ``auto`` gives the maps of the call made before --metal
    existed (no metal, the highlight found inside), bit for bit."""
    capture_one(_Chrome(), _photo(tmp_path), tmp_path / "out", CaptureOptions(refine=4, relit="none"))
    (photo, start, steps, kw, got), = refine_calls
    assert kw["metal"] == "auto"
    before = {k: v for k, v in kw.items() if k not in ("metal", "highlight")}
    old = refine_prediction(photo, start, steps, **before)
    for name, want in old.svbrdf.maps().items():
        assert torch.equal(getattr(got.svbrdf, name), want), name


@pytest.fixture(scope="module")
def model():
    return sm.load_model("pretrained")


@pytest.mark.parametrize("refine", [0, 2])
def test_the_python_api_takes_metal(model, refine):
    photo = render(_plastic(48), flash_scene(torch.tensor([[0.0, 0.0, 2.2]]), torch.tensor([10.0]))).clamp(0, 1)[0]
    maps = model.predict(photo, refine, metal="none")
    assert torch.equal(maps.specular, torch.full_like(maps.specular, 0.04))
    with pytest.raises(DataError, match="metal must be auto"):
        model.predict(photo, refine, metal="steel")


def test_the_command_line_takes_metal_none(tmp_path, capsys):
    path = _photo(tmp_path)
    out = tmp_path / "out"
    assert main(["predict", str(path), "-o", str(out), "--refine", "3", "--metal", "none", "--relit", "none"]) == 0
    assert float(_read(out / "plastic", "metallic.png").max()) == 0.0
    assert json.loads((out / "plastic" / "material.json").read_text())["metal"] == "none"
    capsys.readouterr()
    assert main(["predict", str(path), "-o", str(out), "--metal", "steel"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("svbrdf-models") and "--metal" in err and err.count("\n") == 1, err


def test_capture_options_refuse_another_metal():
    with pytest.raises(DataError, match="metal must be auto"):
        CaptureOptions(metal="yes")


def test_a_calibrated_set_takes_metal_none(tmp_path, capsys):
    """Several views refined as one material: the specular held at 0.04 there too."""
    from test_models_calibrated import VIEWS, _scene, _write_set

    photos = torch.cat([render(_plastic(), _scene(p)).clamp(0, 1) for p in VIEWS[:2]])
    folder = _write_set(tmp_path / "plastic-set", photos)
    out = tmp_path / "out"
    argv = ["predict", "--calibrated", str(folder), "-o", str(out), "--refine", "3", "--backend", "eager",
            "--relit", "none", "--metal", "none", "--bits", "16", "--albedo-encoding", "linear"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    specular = _read(out / folder.name, "specular.png")
    assert torch.allclose(specular, torch.full_like(specular, 0.04), atol=1 / 65535)
    assert float(_read(out / folder.name, "metallic.png").max()) == 0.0
    assert json.loads((out / folder.name / "material.json").read_text())["metal"] == "none"


def test_shots_of_the_printed_frame_take_metal_none(tmp_path, capsys):
    pytest.importorskip("cv2", reason="opencv-python-headless (svbrdf-models[photo]) is not installed")
    from shotphotos import PAPER, save, shot
    from test_models_shots import FOV, INTENSITY, QUICK, SHOTS

    files = []
    for k, (name, (camera, exposure, up)) in enumerate(list(SHOTS.items())[:2]):
        photo, _ = shot(_plastic(), camera, intensity=INTENSITY, exposure=exposure, up=up, seed=k)
        files.append(save(tmp_path / f"{name}.png", photo) or tmp_path / f"{name}.png")
    out = tmp_path / "out"
    argv = ["predict", *map(str, files), "--shots", "--fov", FOV, "--strip-albedo", str(PAPER), "-o", str(out),
            "--refine", "3", "--map-size", "64", "--metal", "none", *QUICK]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    folder = out / files[0].stem
    assert float(_read(folder, "metallic.png").max()) == 0.0
    assert json.loads((folder / "material.json").read_text())["metal"] == "none"
