"""The material folder of ``predict`` (svbrdf_models.capture.material): every image says its encoding,
material.json describes it, the glTF and MaterialX files validate, refusals and interruptions
leave nothing half-written.

The validator checks skip when Node's glTF validator or the materialx package is missing, and
fail when CI is set (the README's set-up installs them).
"""

from __future__ import annotations

import json

import pytest
import torch

import svbrdf_models as sm
from conftest import require_materialx, validate_gltf
from svbrdf_models import capture
from svbrdf_models.capture.material import MATERIAL_FORMAT, photo_sha256
from svbrdf_models.capture.one import CaptureOptions, capture_one
from svbrdf_models.cli import main
from svbrdf_models.errors import DataError
from svbrdf_render import (
    MIN_TILEABLE_SIDE,
    SVBRDF,
    Scene,
    read_des18,
    read_image,
    read_png_encoding,
    render,
    seam_error,
    srgb_to_linear,
    to_metal_rough,
    write_image,
)
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb

EIGHT_BIT = 1 / 255 + 1e-6


class _Known:
    """A stand-in predictor that always answers the same maps (``example_material``)."""

    def __init__(self, name: str = "tiles", resolution: int = 64):
        self.resolution = resolution
        self.maps = example_material(name, resolution)
        self.source, self.sha256, self.steps = f"known:{name}", "0" * 64, 0

    def predict(self, photo):
        return self.maps


def _photo_file(folder, name="shot", size=96, material="tiles"):
    maps = example_material(material, size)
    photo = render(maps, Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    return write_image(folder / f"{name}.png", linear_to_srgb(photo))


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """One material folder made with the default options."""
    tmp = tmp_path_factory.mktemp("material")
    path = _photo_file(tmp)
    capture_one(_Known(), path, tmp / "out", CaptureOptions(relit="none"))
    return tmp / "out"


def test_every_image_says_its_encoding_as_material_json_does(folder):
    record = json.loads((folder / "material.json").read_text())
    assert record["format"] == MATERIAL_FORMAT and record["name"] == "shot"
    expected = {"basecolor": "srgb", "diffuse": "srgb", "specular": "srgb", "metallic": "linear",
                "roughness": "linear", "normal": "linear", "metallic_roughness": "linear"}  # fmt: skip
    assert {name: m["encoding"] for name, m in record["maps"].items()} == expected
    for name, entry in record["maps"].items():
        assert read_png_encoding(folder / entry["file"]) == entry["encoding"], name
    for figure in ("input.png", "rerender.png"):
        assert read_png_encoding(folder / figure) == "srgb"
    assert record["normal"]["convention"] == "opengl"
    assert record["photo"]["sha256"] == photo_sha256(folder.parent / "shot.png")
    assert record["model"]["source"] == "known:tiles" and record["refine"] == {"budget": 0}
    for key in ("created", "svbrdf_render", "svbrdf_models", "torch"):
        assert record["provenance"][key]
    assert all((folder / f).is_file() for f in ("material.gltf", "material.mtlx", "index.html"))


def test_the_maps_are_the_conversion_of_the_prediction(folder):
    """basecolor/metallic are to_metal_rough of the predicted maps; metallic_roughness packs
    roughness in G and metallic in B; diffuse is sRGB-encoded; the normal (n+1)/2."""
    maps = _Known().maps
    mr = to_metal_rough(maps)
    base = read_image(folder / "basecolor.png")
    assert float((base - linear_to_srgb(mr.basecolor[0])).abs().max()) <= EIGHT_BIT
    packed = read_image(folder / "metallic_roughness.png")
    assert torch.equal(packed[1], read_image(folder / "roughness.png", channels=1)[0])
    assert torch.equal(packed[2], read_image(folder / "metallic.png", channels=1)[0])
    assert float(packed[0].abs().max()) == 0.0
    assert float((read_image(folder / "metallic.png", channels=1) - mr.metallic[0]).abs().max()) <= EIGHT_BIT
    diffuse = read_image(folder / "diffuse.png")
    assert float((diffuse - linear_to_srgb(maps.diffuse[0])).abs().max()) <= EIGHT_BIT
    normal = read_image(folder / "normal.png")
    assert float((normal - (maps.normal[0] + 1) / 2).abs().max()) <= EIGHT_BIT


def test_material_files_validate(folder):
    report = validate_gltf(folder / "material.gltf")
    assert report["returncode"] == 0 and report["issues"]["numErrors"] == 0
    assert report["issues"]["numWarnings"] == 0
    require_materialx()
    from svbrdf_render import validate_materialx

    assert validate_materialx(folder / "material.mtlx") == []
    gltf = json.loads((folder / "material.gltf").read_text())
    assert {image["uri"] for image in gltf["images"]} == {"basecolor.png", "metallic_roughness.png", "normal.png"}


def test_directx_normals_keep_an_opengl_copy_for_the_material_files(tmp_path):
    path = _photo_file(tmp_path)
    out = tmp_path / "dx"
    capture_one(_Known(), path, out, CaptureOptions(relit="none", normal_convention="dx"))
    gl, dx = read_image(out / "normal_opengl.png"), read_image(out / "normal.png")
    assert float((dx[1] - (1 - gl[1])).abs().max()) <= EIGHT_BIT and torch.equal(dx[[0, 2]], gl[[0, 2]])
    record = json.loads((out / "material.json").read_text())
    assert record["normal"]["convention"] == "directx"
    gltf = json.loads((out / "material.gltf").read_text())
    assert "normal_opengl.png" in {image["uri"] for image in gltf["images"]}
    assert "normal_opengl.png" in (out / "material.mtlx").read_text()


def test_linear_albedos_exr_and_16_bits(tmp_path):
    exr = pytest.importorskip("OpenEXR")
    path = _photo_file(tmp_path)
    out = tmp_path / "lin"
    options = CaptureOptions(relit="none", albedo_encoding="linear", exr=True, bits=16)
    capture_one(_Known(), path, out, options)
    maps = _Known().maps
    diffuse = read_image(out / "diffuse.png")
    assert read_png_encoding(out / "diffuse.png") == "linear"
    assert float((diffuse - maps.diffuse[0]).abs().max()) <= 1 / 65535 + 1e-6
    assert read_png_encoding(out / "basecolor.png") == "srgb"  # the material files need it so
    pixels = exr.File(str(out / "diffuse.exr")).channels()["RGB"].pixels
    assert abs(pixels.astype("float32") - maps.diffuse[0].permute(1, 2, 0).numpy()).max() < 1e-3
    record = json.loads((out / "material.json").read_text())
    assert record["maps"]["diffuse_exr"]["encoding"] == "linear"


def test_tileable_maps_match_at_their_edges(tmp_path):
    """A material lit unevenly across (a ramp in its diffuse map) has a seam; --tileable removes it."""
    path = _photo_file(tmp_path, size=128)
    out = tmp_path / "tiled"
    known = _Known("tiles", 128)
    ramp = torch.linspace(0, 1, 128).view(1, 1, 1, 128)
    known.maps = SVBRDF(known.maps.normal, 0.5 * known.maps.diffuse + 0.5 * ramp, known.maps.roughness,
                        known.maps.specular)  # fmt: skip
    entry = capture_one(known, path, out, CaptureOptions(relit="none", tileable=True))
    seams = entry["tileable"]
    assert seams["seam_error_after"]["diffuse"] < 1.5 < seams["seam_error_before"]["diffuse"]
    diffuse = srgb_to_linear(read_image(out / "diffuse.png"))[None]
    assert float(seam_error(diffuse)[0]) < 1.5
    assert json.loads((out / "material.json").read_text())["tileable"] == seams


def test_tileable_on_a_small_photo_is_refused_before_any_work(tmp_path):
    path = _photo_file(tmp_path, size=capture.MIN_TILEABLE_PHOTO - 32)
    assert capture.MIN_TILEABLE_PHOTO >= 2 * MIN_TILEABLE_SIDE
    with pytest.raises(capture.PhotoError, match="--tileable needs at least"):
        capture_one(_Known(), path, tmp_path / "out", CaptureOptions(tileable=True))
    assert not (tmp_path / "out").exists()


def test_a_folder_of_another_material_is_refused_and_kept(tmp_path, folder):
    other = _photo_file(tmp_path, name="shot", material="leather")  # same name, another photo
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(DataError, match="holds the material of shot.png"):
        capture_one(_Known(), other, folder, CaptureOptions(relit="none"))
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    maps_only = tmp_path / "maps-only"
    maps_only.mkdir()
    (maps_only / "normal.png").write_bytes(before["normal.png"])
    with pytest.raises(DataError, match="no material.json"):
        capture_one(_Known(), other, maps_only, CaptureOptions(relit="none"))


def test_the_same_photo_again_replaces_its_files_and_leaves_others(tmp_path):
    path = _photo_file(tmp_path)
    out = tmp_path / "out"
    capture_one(_Known(), path, out, CaptureOptions(relit="gif"))
    (out / "notes.txt").write_text("mine\n")
    capture_one(_Known("leather"), path, out, CaptureOptions(relit="none"))
    assert (out / "notes.txt").read_text() == "mine\n"
    assert not (out / "relit.gif").exists()  # the first run's, not written by the second
    diffuse = read_image(out / "diffuse.png")
    assert float((diffuse - linear_to_srgb(example_material("leather", 64).diffuse[0])).abs().max()) <= EIGHT_BIT
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left


@pytest.mark.parametrize("exception", [KeyboardInterrupt, OSError(28, "No space left on device")])
def test_a_failure_while_writing_leaves_the_folder_as_it_was(tmp_path, monkeypatch, exception):
    path = _photo_file(tmp_path)
    out = tmp_path / "out"
    capture_one(_Known(), path, out, CaptureOptions(relit="none"))
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args, **kwargs):
        raise exception

    monkeypatch.setattr("svbrdf_render.viewer.write_viewer", broken)
    with pytest.raises((KeyboardInterrupt, OSError)):
        capture_one(_Known("leather"), path, out, CaptureOptions(relit="none"))
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "shot.png"]
    fresh = tmp_path / "fresh"
    with pytest.raises((KeyboardInterrupt, OSError)):
        capture_one(_Known(), path, fresh, CaptureOptions(relit="none"))
    assert not fresh.exists()


# -- the command ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, words",
    [
        (["--normal", "vulkan"], "expected opengl (gl) or directx (dx)"),
        (["--albedo-encoding", "rec2020"], "invalid choice"),
    ],
)
def test_bad_conventions_are_one_line_exit_2(tmp_path, capsys, args, words):
    path = _photo_file(tmp_path)
    code = main(["predict", str(path), "-o", str(tmp_path / "out"), *args])
    err = capsys.readouterr().err
    assert code == 2 and words in err and len(err.strip().splitlines()) <= 2 and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_command_refuses_another_material_before_loading_the_model(tmp_path, capsys, monkeypatch):
    path = _photo_file(tmp_path)
    (tmp_path / "out" / "shot").mkdir(parents=True)
    (tmp_path / "out" / "shot" / "diffuse.png").write_bytes(path.read_bytes())

    def no_model(*args, **kwargs):
        raise AssertionError("the model was loaded")

    monkeypatch.setattr("svbrdf_models.commands.predict._load_predict_model", no_model)
    code = main(["predict", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "holds maps (diffuse.png) with no material.json" in err
    assert len(err.strip().splitlines()) == 1


def test_command_dx_short_name(tmp_path, capsys):
    path = _photo_file(tmp_path)
    code = main(["predict", str(path), "-o", str(tmp_path / "out"), "--refine", "0", "--relit", "none",
                 "--normal", "dx"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    record = json.loads((tmp_path / "out" / "shot" / "material.json").read_text())
    assert record["normal"]["convention"] == "directx"
    assert record["model"]["sha256"] == sm.load_model("pretrained").sha256


# -- real photos and unseen materials ------------------------------------------------------------------


@pytest.mark.data
@pytest.mark.slow
def test_real_photos_and_unseen_materials_give_valid_material_files(tmp_path, shared_data):
    """Three real photos and three unseen-dev materials (their photo tiles) through the shipped
    model: glTF (Khronos validator) and MaterialX validate with no error."""
    from svbrdf_render import validate_materialx

    real = sorted((shared_data / "real-dev").glob("*.png"))[:3]
    unseen = []
    for strip in sorted((shared_data / "unseen-dev").glob("*.png"))[:3]:
        photo = read_des18(strip).input[0]
        unseen.append(write_image(tmp_path / strip.name, photo))  # Des18 inputs are stored as is
    model = sm.load_model("pretrained")
    require_materialx()
    for path in (*real, *unseen):
        options = CaptureOptions(relit="none", linear=path in unseen)
        out = tmp_path / "out" / path.stem
        capture_one(model, path, out, options)
        report = validate_gltf(out / "material.gltf")
        assert report["issues"]["numErrors"] == 0, (path, report["issues"])
        assert validate_materialx(out / "material.mtlx") == [], path
