"""Material files beside the maps: a glTF 2.0 asset and a MaterialX document that reference the
images, checked by the official validators (the Khronos glTF validator, run by
tools/gltf-validate/validate.mjs under Node, and MaterialX's own validation against its
standard libraries).

The validator tests skip when Node, the validator's node_modules or the ``materialx`` package
is missing, and fail instead when the environment variable CI is set: the README's set-up
installs them, so a CI run that skipped them would prove nothing.
"""

from __future__ import annotations

import base64
import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pytest
import torch

from conftest import require_materialx, validate_gltf
from svbrdf_render import SVBRDFError, write_image
from svbrdf_render.formats import write_gltf, write_materialx
from svbrdf_render.plumbing import temporary_path

SIDE = 8  # pixels: a power of two, so the validator has no IMAGE_NPOT_DIMENSIONS note to make
# glTF codes (the specification's numbers), spelled out here rather than imported
FLOAT, UNSIGNED_SHORT, REPEAT, LINEAR, LINEAR_MIPMAP_LINEAR = 5126, 5123, 10497, 9729, 9987
COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
# Validator notes (severity 2 = info, 3 = hint) that are no defect of the file: maps whose side
# is not a power of two (a 288-pixel Des18 tile) are legal glTF; old WebGL 1 can't mipmap them.
JUSTIFIED_NOTES = {"IMAGE_NPOT_DIMENSIONS"}


@pytest.fixture
def materialx():
    return require_materialx()


def _maps(folder: Path, names: dict[str, str] | None = None) -> Path:
    """Small real PNGs under the names the command lines write (or ``names``)."""
    names = {
        "basecolor": "basecolor.png", "metallic": "metallic.png", "roughness": "roughness.png",
        "metallic_roughness": "metallic_roughness.png", "normal": "normal_opengl.png", **(names or {}),
    }  # fmt: skip
    g = torch.Generator().manual_seed(0)
    packed = torch.rand(3, SIDE, SIDE, generator=g)
    packed[0] = 0  # glTF packing: R unused, G roughness, B metallic
    tilt = torch.rand(3, SIDE, SIDE, generator=g) - torch.tensor([0.5, 0.5, -1.0])[:, None, None]
    normal = torch.nn.functional.normalize(tilt, dim=0)  # unit, z > 0
    images = {
        "basecolor": torch.rand(3, SIDE, SIDE, generator=g),
        "metallic": torch.rand(1, SIDE, SIDE, generator=g),
        "roughness": torch.rand(1, SIDE, SIDE, generator=g),
        "metallic_roughness": packed,
        "normal": (normal + 1) / 2,
    }
    for role, image in images.items():
        write_image(folder / names[role], image)
    return folder


def _gltf(path: Path) -> dict:
    return json.loads(path.read_text())


def _accessor(doc: dict, index: int) -> np.ndarray:
    """Accessor ``index`` decoded from the embedded buffer, as an (count, components) array."""
    accessor = doc["accessors"][index]
    view = doc["bufferViews"][accessor["bufferView"]]
    uri = doc["buffers"][view["buffer"]]["uri"]
    assert uri.startswith("data:application/octet-stream;base64,")
    data = base64.b64decode(uri.split(",", 1)[1])
    dtype = {FLOAT: "<f4", UNSIGNED_SHORT: "<u2"}[accessor["componentType"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    n = accessor["count"] * COMPONENTS[accessor["type"]]
    return np.frombuffer(data, dtype=dtype, count=n, offset=start).reshape(accessor["count"], -1)


def _primitive(doc: dict) -> dict:
    (node,) = doc["scenes"][doc["scene"]]["nodes"]
    (primitive,) = doc["meshes"][doc["nodes"][node]["mesh"]]["primitives"]
    return primitive


def _texture_uri(doc: dict, info: dict) -> str:
    return unquote(doc["images"][doc["textures"][info["index"]]["source"]]["uri"])


# -- glTF: the Khronos validator ---------------------------------------------------------------------


def test_gltf_passes_the_khronos_validator_with_its_images_loaded(tmp_path):
    path = write_gltf(_maps(tmp_path) / "material.gltf", extras={"model": "ours-mix-cpu", "seed": 3})
    report = validate_gltf(path)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    assert {m["code"] for m in issues["messages"]} <= JUSTIFIED_NOTES
    assert report["returncode"] == 0
    info = report["info"]
    assert (info["drawCallCount"], info["totalVertexCount"], info["totalTriangleCount"]) == (1, 4, 2)
    assert info["materialCount"] == 1 and info["hasTextures"] and info["hasDefaultScene"]
    # the validator decoded every referenced PNG (it checks them only when it loads them)
    images = {r["uri"]: r["image"] for r in info["resources"] if r["pointer"].startswith("/images/")}
    assert set(images) == {"basecolor.png", "metallic_roughness.png", "normal_opengl.png"}
    assert all((im["width"], im["height"], im["format"]) == (SIDE, SIDE, "rgb") for im in images.values())


def test_the_validator_run_reports_a_missing_image_as_an_error(tmp_path):
    """The harness really loads the images: without them the same file fails."""
    _maps(tmp_path)
    (tmp_path / "normal_opengl.png").unlink()
    report = validate_gltf(write_gltf(tmp_path / "material.gltf"))
    assert report["returncode"] == 1 and report["issues"]["numErrors"] == 1
    (message,) = report["issues"]["messages"]
    assert message["code"] == "IO_ERROR" and message["pointer"] == "/images/2/uri"


def test_image_names_that_need_percent_encoding_reach_their_files(tmp_path):
    names = {"basecolor": "my maps/base colour #1.png", "metallic_roughness": "my maps/mr%.png",
             "normal": "my maps/normal é.png"}  # fmt: skip
    (tmp_path / "my maps").mkdir()
    _maps(tmp_path, names)
    path = write_gltf(tmp_path / "material.gltf", **names)
    doc = _gltf(path)
    uris = [image["uri"] for image in doc["images"]]
    assert all(" " not in u and "#" not in u and "é" not in u for u in uris)  # RFC 3986 characters only
    assert [unquote(u) for u in uris] == list(names.values())
    report = validate_gltf(path)
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report["issues"]


# -- glTF: what the file says -----------------------------------------------------------------------


def test_gltf_material_references_the_given_images(tmp_path):
    path = write_gltf(tmp_path / "a.gltf", basecolor="b.png", metallic_roughness="sub/mr.jpg",
                      normal="../n.jpeg", name="brick 7", extras={"model": "m", "scores": [0.1, 0.2]})  # fmt: skip
    doc = _gltf(path)
    assert doc["asset"]["version"] == "2.0" and "svbrdf" in doc["asset"]["generator"]
    primitive = _primitive(doc)
    material = doc["materials"][primitive["material"]]
    pbr = material["pbrMetallicRoughness"]
    assert _texture_uri(doc, pbr["baseColorTexture"]) == "b.png"
    assert _texture_uri(doc, pbr["metallicRoughnessTexture"]) == "sub/mr.jpg"
    assert _texture_uri(doc, material["normalTexture"]) == "../n.jpeg"
    mimes = {unquote(i["uri"]): i["mimeType"] for i in doc["images"]}
    assert mimes == {"b.png": "image/png", "sub/mr.jpg": "image/jpeg", "../n.jpeg": "image/jpeg"}
    assert pbr.get("baseColorFactor", [1, 1, 1, 1]) == [1, 1, 1, 1]
    assert pbr.get("metallicFactor", 1) == 1 and pbr.get("roughnessFactor", 1) == 1
    assert material["normalTexture"].get("scale", 1) == 1
    assert material["name"] == "brick 7" and material["extras"] == {"model": "m", "scores": [0.1, 0.2]}
    for texture in doc["textures"]:
        sampler = doc["samplers"][texture["sampler"]]
        assert sampler["wrapS"] == sampler["wrapT"] == REPEAT  # tiled maps repeat
        assert sampler["magFilter"] == LINEAR and sampler["minFilter"] == LINEAR_MIPMAP_LINEAR
    assert set(primitive["attributes"]) == {"POSITION", "NORMAL", "TANGENT", "TEXCOORD_0"}


@pytest.mark.parametrize("size", [1.0, 0.05, 3.7])
def test_gltf_plane_has_its_extent_and_the_image_top_left_at_its_top_left(tmp_path, size):
    doc = _gltf(write_gltf(tmp_path / "a.gltf", size=size))
    primitive = _primitive(doc)
    attributes = primitive["attributes"]
    p = _accessor(doc, attributes["POSITION"]).astype(np.float64)
    uv = _accessor(doc, attributes["TEXCOORD_0"]).astype(np.float64)
    n = _accessor(doc, attributes["NORMAL"]).astype(np.float64)
    t = _accessor(doc, attributes["TANGENT"]).astype(np.float64)
    triangles = _accessor(doc, primitive["indices"]).reshape(-1, 3)
    # extent: a square of side 2 * size centred at the origin in z = 0; min/max as declared
    np.testing.assert_allclose(p.min(0), [-size, -size, 0], rtol=1e-6)
    np.testing.assert_allclose(p.max(0), [size, size, 0], rtol=1e-6)
    accessor = doc["accessors"][attributes["POSITION"]]
    np.testing.assert_array_equal(accessor["min"], p.min(0))
    np.testing.assert_array_equal(accessor["max"], p.max(0))
    # glTF's UV (0, 0) is the image's top-left and v grows down the image: every vertex lies
    # where its UV puts it on an unflipped image whose top edge is at y = +size
    np.testing.assert_allclose(p[:, 0], -size + 2 * size * uv[:, 0], rtol=1e-6)
    np.testing.assert_allclose(p[:, 1], size - 2 * size * uv[:, 1], rtol=1e-6)
    np.testing.assert_allclose(p[np.all(uv == 0, axis=1)], [[-size, size, 0]], rtol=1e-6)
    # the two triangles cover the square, face +Z (counter-clockwise), and agree with NORMAL
    a, b, c = (p[triangles[:, i]] for i in range(3))
    face = np.cross(b - a, c - a)
    assert np.all(face[:, 2] > 0) and np.allclose(face[:, :2], 0)
    np.testing.assert_allclose(face[:, 2].sum() / 2, (2 * size) ** 2, rtol=1e-6)
    np.testing.assert_allclose(n, np.tile([0, 0, 1], (4, 1)))
    # TANGENT is dP/du, and cross(N, T) * w (glTF's bitangent, the normal map's green axis)
    # points to the image's top, i.e. against dP/dv: the OpenGL convention of normal_opengl.png
    for tri in triangles:
        dp = p[tri[1:]] - p[tri[0]]
        duv = uv[tri[1:]] - uv[tri[0]]
        dp_du, dp_dv = np.linalg.solve(duv, dp)  # rows: dP/du, dP/dv
        for i in tri:
            np.testing.assert_allclose(t[i, :3], dp_du / np.linalg.norm(dp_du), atol=1e-7)
            bitangent = np.cross(n[i], t[i, :3]) * t[i, 3]
            np.testing.assert_allclose(bitangent, -dp_dv / np.linalg.norm(dp_dv), atol=1e-7)


def test_gltf_overwrites_in_place_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a.gltf"
    write_gltf(path, basecolor="first.png")
    write_gltf(path, basecolor="second.png")
    assert [unquote(i["uri"]) for i in _gltf(path)["images"]][0] == "second.png"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gltf"]
    assert not temporary_path(path).exists()


# -- MaterialX ------------------------------------------------------------------------------------------


def test_materialx_validates_against_the_standard_libraries(tmp_path, materialx):
    from svbrdf_render.formats import validate_materialx

    path = write_materialx(_maps(tmp_path) / "material.mtlx")
    assert validate_materialx(path) == []
    document = materialx.createDocument()
    materialx.readFromXmlFile(document, str(path))
    libraries = materialx.createDocument()
    materialx.loadLibraries(materialx.getDefaultDataLibraryFolders(), materialx.getDefaultDataSearchPath(), libraries)
    document.importLibrary(libraries)
    shader = document.getNode("SR_svbrdf_material")
    assert shader.getNodeDef().getNodeString() == "gltf_pbr"
    material = document.getNode("svbrdf_material")
    assert material.getType() == "material" and material.getConnectedNode("surfaceshader") == shader


def test_materialx_references_the_images_with_their_colour_spaces(tmp_path):
    path = write_materialx(tmp_path / "m.mtlx", basecolor="a/b c.png", metallic="m.jpg",
                           roughness="../r.png", normal="n.png", name="brick_7")  # fmt: skip
    root = ET.parse(path).getroot()
    assert root.tag == "materialx" and root.get("version") in ("1.38", "1.39")
    images = {node.get("type"): [] for node in root.iter("image")}
    for node in root.iter("image"):
        (file_input,) = [i for i in node.iter("input") if i.get("name") == "file"]
        images[node.get("type")].append((file_input.get("value"), file_input.get("colorspace")))
    # only the base colour is sRGB-encoded; the data maps are read as stored
    assert images == {"color3": [("a/b c.png", "srgb_texture")], "float": [("m.jpg", None), ("../r.png", None)],
                      "vector3": [("n.png", None)]}  # fmt: skip
    (normalmap,) = root.iter("normalmap")
    (normal_image,) = [node for node in root.iter("image") if node.get("type") == "vector3"]
    assert normalmap.find("input[@name='in']").get("nodename") == normal_image.get("name")
    (material,) = root.iter("surfacematerial")
    assert material.get("name") == "brick_7"
    assert [s.get("name") for s in root.iter("gltf_pbr")] == [material.find("input").get("nodename")]


def test_materialx_shader_code_decodes_only_the_base_colour_from_srgb(tmp_path, materialx):
    """A renderer can use it: MaterialX generates GLSL with one sampler per image and the sRGB
    decoding on the base colour alone."""
    gen_shader = pytest.importorskip("MaterialX.PyMaterialXGenShader")
    gen_glsl = pytest.importorskip("MaterialX.PyMaterialXGenGlsl")
    path = write_materialx(_maps(tmp_path) / "material.mtlx")
    document = materialx.createDocument()
    materialx.readFromXmlFile(document, str(path))
    libraries = materialx.createDocument()
    materialx.loadLibraries(materialx.getDefaultDataLibraryFolders(), materialx.getDefaultDataSearchPath(), libraries)
    document.importLibrary(libraries)
    generator = gen_glsl.GlslShaderGenerator.create()
    colour = gen_shader.DefaultColorManagementSystem.create(generator.getTarget())
    colour.loadLibrary(libraries)
    generator.setColorManagementSystem(colour)
    context = gen_shader.GenContext(generator)
    context.registerSourceCodeSearchPath(materialx.getDefaultDataSearchPath())
    shader = generator.generate("svbrdf", document.getNode("svbrdf_material"), context)
    code = shader.getSourceCode(gen_shader.PIXEL_STAGE)
    for image in ("basecolor", "metallic", "roughness", "normal"):
        assert f"uniform sampler2D {image}_image_file;" in code
    calls = [line.strip() for line in code.splitlines() if "srgb_texture_to_lin_rec709" in line and "(" in line
             and not line.lstrip().startswith("void")]  # fmt: skip
    assert len(calls) == 1 and "basecolor_image_out" in calls[0]


def _tampered(path: Path, old: str, new: str) -> Path:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ('name="base_color"', 'name="base_colour"', "base_colour"),  # not an input of gltf_pbr
        ('<normalmap name="normalmap"', '<normalmop name="normalmap"', "normalmop"),  # no such node
        ('nodename="normal_image"', 'nodename="nowhere"', "nowhere"),  # dangling connection
        ('value="roughness.png"', 'value="gone.png"', "gone.png"),  # missing image
    ],
)
def test_validate_materialx_finds_what_is_wrong(tmp_path, materialx, old, new, expected):
    from svbrdf_render.formats import validate_materialx

    path = write_materialx(_maps(tmp_path) / "material.mtlx")
    if "normalmop" in new:
        _tampered(path, "</normalmap>", "</normalmop>")
    problems = validate_materialx(_tampered(path, old, new))
    assert problems and any(expected in p for p in problems), problems


def test_validate_materialx_reports_a_file_that_is_not_materialx(tmp_path, materialx):
    from svbrdf_render.formats import validate_materialx

    (tmp_path / "x.mtlx").write_text("not xml at all")
    (problem,) = validate_materialx(tmp_path / "x.mtlx")
    assert "x.mtlx" in problem and "MaterialX" in problem
    with pytest.raises(SVBRDFError, match="no such file"):
        validate_materialx(tmp_path / "absent.mtlx")


def test_validate_materialx_says_how_to_install_the_package(tmp_path, monkeypatch):
    from svbrdf_render.formats import validate_materialx

    path = write_materialx(tmp_path / "m.mtlx")
    monkeypatch.setitem(sys.modules, "MaterialX", None)  # import MaterialX now raises ImportError
    with pytest.raises(ImportError, match=r"materialx.*pip install"):
        validate_materialx(path)


# -- bad input ------------------------------------------------------------------------------------------


WRITERS = {"gltf": (write_gltf, "normal"), "mtlx": (write_materialx, "roughness")}


def _refused(writer, path: Path, match: str, **kwargs) -> str:
    with pytest.raises(SVBRDFError, match=match) as caught:
        writer(path, **kwargs)
    message = str(caught.value)
    assert "\n" not in message
    assert not path.exists() and not temporary_path(path).exists()
    return message


@pytest.mark.parametrize("suffix", WRITERS)
def test_a_folder_that_does_not_exist_is_refused(tmp_path, suffix):
    writer, _ = WRITERS[suffix]
    message = _refused(writer, tmp_path / "no" / f"m.{suffix}", "does not exist")
    assert str(tmp_path / "no") in message and "make the folder" in message
    assert not (tmp_path / "no").exists()
    (tmp_path / "file").write_text("")
    _refused(writer, tmp_path / "file" / f"m.{suffix}", "is not a folder")


@pytest.mark.parametrize("suffix", WRITERS)
def test_a_wrong_suffix_is_refused(tmp_path, suffix):
    writer, _ = WRITERS[suffix]
    _refused(writer, tmp_path / "m.json", rf"must end in \.{suffix}")


@pytest.mark.parametrize("suffix", WRITERS)
@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("", "is empty"),
        ("/abs/n.png", "absolute path or a URL"),
        ("C:/maps/n.png", "absolute path or a URL"),
        ("https://example.com/n.png", "absolute path or a URL"),
        ("file:n.png", "absolute path or a URL"),
        ("maps\\n.png", "backslash"),
        ("maps//n.png", "empty folder name"),
        ("maps/", "empty folder name"),
        ("n.tif", "not a .png, .jpg or .jpeg"),
        ("n", "not a .png, .jpg or .jpeg"),
        ("n\n.png", "control character"),
        (None, "not a file name"),
        (3, "not a file name"),
    ],
)
def test_image_names_that_are_not_relative_file_names_are_refused(tmp_path, suffix, name, reason):
    writer, role = WRITERS[suffix]
    message = _refused(writer, tmp_path / f"m.{suffix}", reason, **{role: name})
    assert f"{role}=" in message
    assert "relative to the material file's folder" in message or "as text" in message


@pytest.mark.parametrize("size", [0, -1.0, float("nan"), float("inf"), True, "1", 1e39, 1e-50])
def test_a_bad_gltf_size_is_refused(tmp_path, size):
    _refused(write_gltf, tmp_path / "m.gltf", "size=", size=size)


@pytest.mark.parametrize("extras", [[1, 2], "text", {"x": float("nan")}, {"x": object()}])
def test_gltf_extras_that_are_not_a_json_object_are_refused(tmp_path, extras):
    _refused(write_gltf, tmp_path / "m.gltf", "extras", extras=extras)


@pytest.mark.parametrize("name", ["", "9lives", "brick 7", "a-b", None])
def test_a_materialx_name_that_is_not_a_materialx_name_is_refused(tmp_path, name):
    _refused(write_materialx, tmp_path / "m.mtlx", "not a MaterialX name", name=name)


@pytest.mark.parametrize("suffix", WRITERS)
def test_a_folder_in_the_place_of_the_file_is_refused_and_left_alone(tmp_path, suffix):
    writer, _ = WRITERS[suffix]
    (tmp_path / f"m.{suffix}").mkdir()
    with pytest.raises(SVBRDFError, match="a folder is in its place"):
        writer(tmp_path / f"m.{suffix}")
    assert (tmp_path / f"m.{suffix}").is_dir() and list(tmp_path.iterdir()) == [tmp_path / f"m.{suffix}"]
