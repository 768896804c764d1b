"""MaterialX material files: :func:`write_materialx`, a ``.mtlx`` document (XML) that reads the
map images, and :func:`validate_materialx`, which checks one.

The document holds image nodes, a normal map node, a ``gltf_pbr`` surface shader and a surface
material: the material a glTF file of :mod:`~svbrdf_render.formats.gltf` holds, from the same
images (their roles, names and checks are that module's). :func:`validate_materialx`
checks a document against the MaterialX standard libraries (the ``materialx`` package, imported
on first use).
"""

from __future__ import annotations

import os
import re
import unicodedata
import xml.etree.ElementTree as ET
from pathlib import Path

from .._optional import require
from ..errors import SVBRDFError
from ..plumbing import write_text
from .gltf import DEFAULT_FILES, image_names, material_path

__all__ = ["MATERIALX_VERSION", "MATERIALX_SHADER", "materialx_name", "write_materialx", "validate_materialx"]

#: The MaterialX version the documents declare. 1.38 documents are read by 1.38 tools as they are
#: and upgraded on load by 1.39 ones (the nodes used here did not change between the two).
MATERIALX_VERSION = "1.38"
#: The MaterialX surface shader: the glTF metallic-roughness model, defined in the MaterialX
#: standard libraries since 1.38.4, so both files describe the same material.
MATERIALX_SHADER = "gltf_pbr"

# MaterialX element names: letters, digits and underscores, not starting with a digit.
_MTLX_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def materialx_name(text: str) -> str:
    """A MaterialX element name (ASCII letters, digits, underscores, not starting with a digit)
    made of any ``text``, such as a photo's name: accents dropped (``café`` -> ``cafe``), every
    other character an underscore, and ``material`` for a text with no ASCII letter or digit
    left (``фото``)."""
    folded = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    cleaned = "".join(c if c.isalnum() else "_" for c in folded)
    if not any(c.isalnum() for c in cleaned):
        cleaned = "material"
    return cleaned if not cleaned[0].isdigit() else f"m_{cleaned}"


def _sub(parent: ET.Element, tag: str, **attributes: str) -> ET.Element:
    return ET.SubElement(parent, tag, attributes)


def _materialx_graph(root: ET.Element, graph_name: str, files: dict[str, str]) -> dict[str, tuple[str, str]]:
    """The node graph reading the four images (see :func:`write_materialx`); returns its
    outputs, ``shader input -> (graph output, type)``."""
    graph = _sub(root, "nodegraph", name=graph_name)
    # (image node, its type, the file's colour space or None for raw data, shader input)
    images = [
        ("basecolor", "color3", "srgb_texture", "base_color"),
        ("metallic", "float", None, "metallic"),
        ("roughness", "float", None, "roughness"),
        ("normal", "vector3", None, None),
    ]
    outputs: dict[str, tuple[str, str]] = {}  # shader input -> (graph output, type)
    for role, kind, colorspace, shader_input in images:
        node = _sub(graph, "image", name=f"{role}_image", type=kind)
        file_input = _sub(node, "input", name="file", type="filename", value=files[role])
        if colorspace:
            file_input.set("colorspace", colorspace)
        for address in ("uaddressmode", "vaddressmode"):
            _sub(node, "input", name=address, type="string", value="periodic")
        if shader_input:
            outputs[shader_input] = (f"{shader_input}_output", kind)
    normalmap = _sub(graph, "normalmap", name="normalmap", type="vector3")
    _sub(normalmap, "input", name="in", type="vector3", nodename="normal_image")
    _sub(normalmap, "input", name="scale", type="float", value="1.0")
    outputs["normal"] = ("normal_output", "vector3")
    nodes = {"base_color": "basecolor_image", "metallic": "metallic_image",
             "roughness": "roughness_image", "normal": "normalmap"}  # fmt: skip
    for shader_input, (output, kind) in outputs.items():
        _sub(graph, "output", name=output, type=kind, nodename=nodes[shader_input])
    return outputs


def _materialx_material(
    root: ET.Element, name: str, graph_name: str, outputs: dict[str, tuple[str, str]]
) -> None:
    """The shader ``SR_<name>`` fed by the graph's outputs, and the material ``<name>`` using it."""
    shader_name = f"SR_{name}"
    shader = _sub(root, MATERIALX_SHADER, name=shader_name, type="surfaceshader")
    for shader_input, (output, kind) in outputs.items():
        _sub(shader, "input", name=shader_input, type=kind, nodegraph=graph_name, output=output)
    material = _sub(root, "surfacematerial", name=name, type="material")
    _sub(material, "input", name="surfaceshader", type="surfaceshader", nodename=shader_name)


def write_materialx(
    path: str | os.PathLike,
    *,
    basecolor: str = DEFAULT_FILES["basecolor"],
    metallic: str = DEFAULT_FILES["metallic"],
    roughness: str = DEFAULT_FILES["roughness"],
    normal: str = DEFAULT_FILES["normal"],
    name: str = "svbrdf_material",
) -> Path:
    """Write a MaterialX document (``.mtlx``) whose surface material reads the maps.

    Layout: a node graph ``NG_<name>`` holds four ``image`` nodes (base colour as ``color3``
    with ``colorspace="srgb_texture"``; metallic and roughness as ``float``; the normal map as
    ``vector3``: MaterialX applies colour transforms to colour types only, so those three are
    read raw) and a ``normalmap`` node (tangent space, (n + 1) / 2, OpenGL convention as
    MaterialX expects), with one output per shader input. The document's working colour space
    is ``lin_rec709``. A ``gltf_pbr`` shader ``SR_<name>`` takes base colour, metallic,
    roughness and normal from the graph; the ``surfacematerial`` ``<name>`` takes the shader.

    Why ``gltf_pbr`` (:data:`MATERIALX_SHADER`) and not ``standard_surface``: the maps are
    glTF metallic-roughness maps (base colour, metalness, perceptual roughness with GGX
    alpha = roughness^2, dielectric F0 = 0.04), which is exactly what ``gltf_pbr`` defines;
    ``standard_surface`` has its own specular layer, weights and roughness meaning, so the same
    maps would give a somewhat different material. The document declares MaterialX
    :data:`MATERIALX_VERSION`; ``gltf_pbr`` needs a MaterialX library of 1.38.4 or later.

    Texture coordinates are the host's UV set 0; MaterialX puts UV (0, 0) at the image's
    bottom-left corner (unlike glTF), addressing is periodic (the maps tile) and filtering linear.
    File names are resolved relative to the document's folder.

    Args:
        path: the file to write, ending in ``.mtlx``; its folder must exist.
        basecolor, metallic, roughness, normal: the images' file names relative to ``path``'s
            folder (``.png``, ``.jpg`` or ``.jpeg``).
        name: the material's name: letters, digits and ``_``, not starting with a digit
            (:func:`materialx_name` makes one of any text).

    Returns:
        ``path``. Raises :class:`~svbrdf_render.errors.SVBRDFError` on a bad argument and
        :class:`~svbrdf_render.errors.OutputError` when the file cannot be written.
    """
    writer = "write_materialx"
    path = material_path(path, ".mtlx", writer)
    files = image_names(writer, basecolor=basecolor, metallic=metallic, roughness=roughness, normal=normal)
    if not isinstance(name, str) or not _MTLX_NAME.match(name):
        raise SVBRDFError(
            f"{writer}: name={name!r} is not a MaterialX name; use letters, digits and '_', "
            "not starting with a digit (e.g. 'svbrdf_material')"
        )
    root = ET.Element("materialx", {"version": MATERIALX_VERSION, "colorspace": "lin_rec709"})
    outputs = _materialx_graph(root, f"NG_{name}", files)
    _materialx_material(root, name, f"NG_{name}", outputs)

    ET.indent(root, space="  ")
    text = ET.tostring(root, encoding="unicode", xml_declaration=False)
    return write_text(path, '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n")


def validate_materialx(path: str | os.PathLike) -> list[str]:
    """The problems MaterialX finds in the document at ``path``; an empty list when it is valid.

    Three checks, with the MaterialX standard data libraries shipped with the ``materialx``
    package (import name ``MaterialX``, imported on first use) loaded into the document:

    - the document's own ``validate`` (names, types, connections, and each node's inputs
      against its definition);
    - every node has a definition in the libraries (``validate`` passes a node of an unknown
      kind, which no renderer could draw);
    - every image file the document names exists (relative names resolve against the
      document's folder, after any ``fileprefix``), as the glTF validator checks for glTF.

    A document of an older version is upgraded on reading, as every MaterialX reader does. A
    file that is not MaterialX XML gives one problem, not an exception. Raises
    :class:`ImportError` saying how to install the package when it is missing.
    """
    mx = require("MaterialX", "materialx", "validating a MaterialX document", extra="materialx")
    path = Path(path)
    if not path.is_file():
        raise SVBRDFError(f"validate_materialx: {path}: no such file; give the path of a .mtlx file")
    document = mx.createDocument()
    try:
        mx.readFromXmlFile(document, str(path))
    except Exception as e:  # MaterialX raises its own ExceptionParseError, ExceptionFileMissing...
        return [f"{path}: cannot read it as MaterialX: {str(e).strip() or type(e).__name__}"]
    # the document's own elements, listed before the libraries join it
    own = list(document.traverseTree())
    nodes = [e.getNamePath() for e in own if isinstance(e, mx.Node)]
    files = [e for e in own if isinstance(e, mx.Input) and e.getType() == "filename"]
    libraries = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), libraries)
    document.importLibrary(libraries)

    valid, message = document.validate()
    problems = [line.strip() for line in message.splitlines() if line.strip()]
    if not valid and not problems:
        problems.append(f"{path}: MaterialX says the document is not valid (no message)")
    for name_path in nodes:
        node = document.getDescendant(name_path)
        if node.getNodeDef() is None:
            problems.append(
                f"node {name_path}: no definition of a '{node.getCategory()}' node of type "
                f"'{node.getType()}' in the MaterialX {mx.getVersionString()} libraries"
            )
    for file_input in files:
        value = file_input.getResolvedValueString()
        where = f"{file_input.getParent().getNamePath()}/{file_input.getName()}"
        if not value:
            problems.append(f"{where}: names no file")
        elif not (path.parent / value).is_file():
            problems.append(f"{where}: image {value!r} not found in {path.resolve().parent}")
    return problems
