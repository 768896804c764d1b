"""Scenes: construction, validation, dict/YAML round trips, configuration shapes."""

from __future__ import annotations

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import (
    DES18_EFFECTS,
    Camera,
    Flash,
    PointLight,
    Scene,
    SceneError,
    render,
    resolve_effects,
)


def _studio() -> Scene:
    return Scene(
        Camera(torch.tensor([0.1, -0.2, 2.5]), fov=40.0),
        (Flash(12.0, offset=torch.tensor([0.05, 0.0, 0.0])),
         PointLight(torch.tensor([1.0, 1.0, 2.0]), 3.0, torch.tensor([1.0, 0.8, 0.6]))),
        {"diffuse": {}, "specular": {"alpha_floor": "clamp"}, "fresnel": {"model": "schlick"},
         "masking": {"model": "smith"}, "cosine": None, "falloff": {}, "exposure": {"ev": 0.5},
         "gamma": {"gamma": 2.0}},
    )


def test_dict_round_trip_renders_identically():
    scene = _studio()
    data = scene.to_dict()
    assert data["lights"][0]["type"] == "flash" and data["effects"]["masking"] == {"model": "smith"}
    back = Scene.from_dict(data)
    m = random_svbrdf(1, 8)
    assert torch.equal(render(m, back), render(m, scene))


def test_yaml_round_trip(tmp_path):
    scene = _studio()
    path = tmp_path / "studio.yaml"
    scene.save(path)
    text = path.read_text()
    assert "2.5" in text and "2.5000" not in text  # float32 values written by their short form
    back = Scene.load(path)
    assert back.to_dict() == scene.to_dict()


def test_yaml_reads_exponent_numbers_without_a_dot_as_numbers(tmp_path):
    # YAML 1.1 (PyYAML) reads 1e1 and 2e-1 as strings; a scene file means the numbers.
    path = tmp_path / "studio.yaml"
    path.write_text("camera: {position: [0, 0, 22e-1]}\nlights: [{type: flash, intensity: 1e1}]\n")
    scene = Scene.load(path)
    assert scene.lights[0].intensity.item() == 10.0
    assert scene.camera.position.tolist() == pytest.approx([0.0, 0.0, 2.2])


def test_effects_are_resolved_with_defaults_and_in_pipeline_order():
    fx = resolve_effects(["gamma", "diffuse", {"noise": {"sigma": 0.1}}, "exposure"])
    assert list(fx) == ["diffuse", "exposure", "noise", "gamma"]
    assert fx["noise"] == {"sigma": 0.1, "shot": 0.0, "seed": 0}
    assert resolve_effects({"gamma": False, "clip": True}) == {"clip": {"max": 1.0}}


@pytest.mark.parametrize(
    "effects, fragment",
    [
        (["difuse"], "unknown effect 'difuse'; did you mean 'diffuse'"),
        ({"gamma": {"gama": 2}}, "did you mean 'gamma'"),
        ({"fresnel": {"model": "exact"}, "specular": {}}, "model must be one of"),
        (["fresnel"], "declare 'specular' too"),
        ({"noise": {"seed": 1.5}}, "seed must be an integer"),
        ({"clip": {"max": -1}}, "max must be > 0"),
        ({"cosine": {"power": 2}}, "takes no parameters"),
        ("diffuse", "got the string"),
    ],
)
def test_effect_declaration_errors(effects, fragment):
    with pytest.raises(SceneError) as e:
        Scene(effects=effects)
    assert fragment in str(e.value)


@pytest.mark.parametrize(
    "data, fragment",
    [
        ({"camera": {"position": [0, 0]}}, "camera position: expected shape (..., 3)"),
        ({"camera": {"fov": 200}}, "fov"),
        ({"lights": [{"type": "spot"}]}, "lights[0]: type must be 'flash' or 'point'"),
        ({"lights": [{"type": "point"}]}, "lights[0]"),
        ({"lights": [{"type": "flash", "intensity": -1}]}, "expected finite values >= 0"),
        ({"light": []}, "unknown key(s) ['light']"),
    ],
)
def test_from_dict_errors_name_the_source_and_key(data, fragment):
    with pytest.raises(SceneError) as e:
        Scene.from_dict(data, source="studio.yaml")
    assert str(e.value).startswith("studio.yaml: ")
    assert fragment in str(e.value)


def test_bad_yaml_file_names_the_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("camera: [unclosed")
    with pytest.raises(SceneError, match="bad.yaml: not valid YAML"):
        Scene.load(p)
    with pytest.raises(SceneError, match="cannot read"):
        Scene.load(tmp_path / "missing.yaml")
    latin = tmp_path / "latin.yaml"
    latin.write_bytes("# lumière\ncamera: {}\n".encode("latin-1"))
    with pytest.raises(SceneError, match="latin.yaml: is not UTF-8 text"):
        Scene.load(latin)


def test_configuration_shapes_broadcast_to_the_output():
    m = random_svbrdf(3, 8)
    assert render(m, Scene()).shape == (3, 3, 8, 8)
    k_scene = Scene(Camera(torch.tensor([[0, 0, 2.0], [0.5, 0, 2.0]])), (Flash(1.0),))
    assert k_scene.config_shape == (2,)
    assert render(m, k_scene).shape == (3, 2, 3, 8, 8)
    bk = Scene(Camera(), (PointLight(torch.rand(3, 4, 3) + torch.tensor([0, 0, 1.0])),))
    assert render(m, bk).shape == (3, 4, 3, 8, 8)
    with pytest.raises(SceneError, match="do not broadcast"):
        Scene(Camera(torch.zeros(2, 3) + 2), (PointLight(torch.ones(3, 3)),))
    with pytest.raises(Exception, match="per-material configurations for 2 materials"):
        render(m, Scene(Camera(), (PointLight(torch.ones(2, 4, 3)),)))


def test_batched_configurations_equal_separate_renders():
    # One call over K configurations is the same as K calls: batching is only batching.
    m = random_svbrdf(2, 8)
    cams = torch.tensor([[0.0, 0.0, 2.2], [0.4, -0.3, 1.8], [-1.0, 0.2, 1.0]])
    lights = torch.tensor([[0.3, 0.3, 2.0], [0.0, 0.0, 3.0], [1.0, 1.0, 0.5]])
    together = render(m, Scene(Camera(cams), (PointLight(lights, 4.0),), DES18_EFFECTS))
    for k in range(3):
        alone = render(m, Scene(Camera(cams[k]), (PointLight(lights[k], 4.0),), DES18_EFFECTS))
        assert torch.allclose(together[:, k], alone, rtol=1e-6, atol=1e-7)


def test_lights_add_up_and_flash_follows_the_camera():
    m = random_svbrdf(1, 8)
    a = PointLight(torch.tensor([0.5, 0.0, 2.0]), 3.0)
    b = PointLight(torch.tensor([-0.5, 0.5, 1.0]), 2.0, torch.tensor([1.0, 0.5, 0.2]))
    cam = Camera(torch.tensor([0.0, 0.2, 2.0]))
    both = render(m, Scene(cam, (a, b)))
    assert torch.allclose(both, render(m, Scene(cam, (a,))) + render(m, Scene(cam, (b,))), atol=1e-6)
    flash = render(m, Scene(cam, (Flash(3.0, offset=torch.tensor([0.1, 0.0, 0.0])),)))
    point = render(m, Scene(cam, (PointLight(torch.tensor([0.1, 0.2, 2.0]), 3.0),)))
    assert torch.allclose(flash, point)


def test_directional_light_has_no_falloff_and_no_parallax():
    m = random_svbrdf(1, 8)
    cam = Camera(torch.tensor([0.0, 0.0, 3.0]))
    near = render(m, Scene(cam, (PointLight(torch.tensor([0.0, 0.6, 0.8]), 2.0, directional=True),)))
    far = render(m, Scene(cam, (PointLight(torch.tensor([0.0, 6.0, 8.0]), 2.0, directional=True),)))
    assert torch.allclose(near, far, rtol=1e-5)  # only the direction matters
    mixed = Scene(
        Camera(torch.tensor([[0.0, 0.0, 3.0], [0.0, 0.0, 3.0]])),
        (PointLight(torch.tensor([[0.0, 0.6, 0.8], [0.0, 0.6, 0.8]]), 2.0,
                    directional=torch.tensor([True, False])),),
    )
    out = render(m, mixed)
    assert torch.allclose(out[:, 0], near[:, :], rtol=1e-5)
    point = render(m, Scene(cam, (PointLight(torch.tensor([0.0, 0.6, 0.8]), 2.0),)))
    assert torch.allclose(out[:, 1], point, rtol=1e-5)
    assert not torch.allclose(out[:, 0], out[:, 1], rtol=1e-2)


def test_a_key_given_twice_in_a_scene_file_is_refused_naming_it(tmp_path):
    p = tmp_path / "twice.yaml"
    p.write_text("camera: {position: [0, 0, 2.5]}\nlights: []\ncamera: {position: [0, 0, 3]}\n")
    with pytest.raises(SceneError) as e:
        Scene.load(p)
    assert str(e.value).startswith(f"{p}: not valid YAML") and "duplicate key 'camera' (lines 1 and 3)" in str(e.value)
    p.write_text("lights:\n  - {type: flash, intensity: 10, intensity: 12}\n")
    with pytest.raises(SceneError, match="duplicate key 'intensity' \\(lines 2 and 2\\)"):
        Scene.load(p)


def test_scene_aliases_are_read_but_an_alias_bomb_is_refused_before_it_is_built(tmp_path):
    p = tmp_path / "shared.yaml"
    p.write_text(
        "camera: {position: [0, 0, 2.5]}\n"
        "lights:\n  - &flash {type: flash, intensity: 10}\n  - *flash\n"
    )
    scene = Scene.load(p)
    assert len(scene.lights) == 2
    bomb = "lights:\n  - &a0 [x, x, x, x, x, x, x, x, x]\n"
    bomb += "".join(f"  - &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 9))
    p.write_text(bomb)
    with pytest.raises(SceneError, match="aliases expand the document to more than 100000 values"):
        Scene.load(p)


@pytest.mark.parametrize(
    "shapes",
    [[(), (3,)], [(2, 1), (1, 4)], [(4,), (2, 4), ()], [(2, 3), (3, 2)], [(0,), (1,)], [(2,), (0,)], [(5, 1, 1)]],
)
def test_the_configuration_broadcast_is_torch_s(shapes):
    from svbrdf_render.scene import _broadcast

    try:
        want = torch.broadcast_shapes(*shapes)
    except RuntimeError:
        want = None
    assert _broadcast([torch.Size(s) for s in shapes]) == want
