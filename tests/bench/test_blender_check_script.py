"""benchmarks/blender_check.py without Blender: how it judges the importer's report, and the
folders and arguments it refuses (one line, exit 2)."""

from __future__ import annotations

import copy

import pytest

from conftest import load_benchmark
from svbrdf_models.capture.one import CaptureOptions, capture_one
from svbrdf_render import Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb

GLTF = {"materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                "metallicRoughnessTexture": {"index": 1}},
                       "normalTexture": {"index": 2}}],
        "textures": [{"source": 0}, {"source": 1}, {"source": 2}],
        "images": [{"uri": "basecolor.png"}, {"uri": "metallic_roughness.png"}, {"uri": "normal.png"}]}  # fmt: skip


def _image(name, colorspace):
    return {"node": "ShaderNodeTexImage", "output": "Color", "image": name, "colorspace": colorspace}


#: What Blender's importer builds from the project's glTF, as the script's Blender side reports it.
REPORT = {
    "corners": [{"uv": [u, v], "xyz": [2 * u - 1, 2 * v - 1, 0.0]} for u in (0, 1) for v in (0, 1)],
    "face_normal": [0.0, 0.0, 1.0],
    "shader": "ShaderNodeBsdfPrincipled",
    "inputs": {
        "Base Color": [_image("basecolor.png", "sRGB")],
        "Metallic": [{"node": "ShaderNodeSeparateColor", "output": "Blue"},
                     _image("metallic_roughness.png", "Non-Color")],
        "Roughness": [{"node": "ShaderNodeSeparateColor", "output": "Green"},
                      _image("metallic_roughness.png", "Non-Color")],
        "Normal": [{"node": "ShaderNodeNormalMap", "output": "Normal", "space": "TANGENT", "strength": 1.0},
                   _image("normal.png", "Non-Color")],
    },
}  # fmt: skip


@pytest.fixture(scope="module")
def check():
    return load_benchmark("blender_check")


def test_the_expected_import_passes(check):
    assert check.judge_report(REPORT, GLTF) == []


@pytest.mark.parametrize(
    "where, change, words",
    [
        (("Base Color", 0, "colorspace"), "Non-Color", "Base Color <-"),
        (("Normal", 1, "colorspace"), "sRGB", "Normal <-"),
        (("Metallic", 0, "output"), "Green", "Metallic <-"),
        (("Normal", 0, "space"), "OBJECT", "Normal <-"),
    ],
)
def test_a_wrong_import_is_named(check, where, change, words):
    report = copy.deepcopy(REPORT)
    name, step, key = where
    report["inputs"][name][step][key] = change
    problems = check.judge_report(report, GLTF)
    assert len(problems) == 1 and problems[0].startswith(words)


def test_a_plane_upside_down_or_another_shader_is_named(check):
    report = copy.deepcopy(REPORT)
    report["corners"][0]["xyz"] = [-1.0, 1.0, 0.0]
    report["face_normal"] = [0.0, 0.0, -1.0]
    problems = check.judge_report(report, GLTF)
    assert any("corner uv 0,0" in p for p in problems) and any("faces" in p for p in problems)
    report = copy.deepcopy(REPORT)
    report["shader"] = "ShaderNodeEmission"
    assert "not a Principled BSDF" in check.judge_report(report, GLTF)[0]


def test_folders_and_arguments_it_refuses(check, tmp_path, capsys):
    maps = example_material("tiles", 64)
    photo = write_image(tmp_path / "shot.png", linear_to_srgb(render(maps, Scene.flash(intensity=12.0))[0]))

    class Known:
        resolution, source = 64, "known"

        def predict(self, photo):
            return maps

    good = tmp_path / "out"
    capture_one(Known(), photo, good, CaptureOptions(relit="none"))
    assert check.check_folder(good) is None
    assert "no such folder" in check.check_folder(tmp_path / "nothing")
    assert "holds no material.gltf" in check.check_folder(tmp_path)
    (good / "metallic_roughness.png").unlink()
    assert "metallic_roughness image is missing" in check.check_folder(good)
    for args in (["--frames", "0,30"], ["--frames", "a"], ["--samples", "0"]):
        assert check.main([str(good), *args]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and err.startswith("blender_check")
