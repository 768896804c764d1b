"""glTF 2.0 material files: :func:`write_gltf`, a ``.gltf`` asset (JSON) that references the map
images, and what a MaterialX file of the same material (:mod:`~svbrdf_render.formats.materialx`)
takes from it: the images' roles and names, and the checks of the file's path.

A folder of map images becomes something an artist drops into Blender, Substance, a game engine
or a web viewer by adding one small file beside the images that says what each one is. The
asset is a flat square patch carrying a metallic-roughness material whose textures are the
images, referenced by relative URI; the geometry is embedded (a base64 data URI), so the asset
is one file plus the images. The files are checked by the Khronos glTF validator in the
repository's tests (``tools/gltf-validate``, a Node script).

Neither material writer reads or checks the images: they may be written before or after. Image
names are file names relative to the material file's folder (``basecolor.png``, ``maps/a.png``,
``../maps/a.png``), with ``/`` between folders, ending in ``.png``, ``.jpg`` or ``.jpeg`` (the
formats core glTF 2.0 allows). Both files are written atomically
(:func:`~svbrdf_render.plumbing.atomic.atomic_output`); the material file's folder must exist.

The maps the writers expect (the names the command lines write, :data:`DEFAULT_FILES`):

============================ =====================================================================
``basecolor.png``            base colour, RGB, sRGB-encoded
``metallic.png``             metalness, grey, linear
``roughness.png``            perceptual roughness, grey, linear (GGX alpha = roughness^2)
``metallic_roughness.png``   glTF packing, linear RGB: G = roughness, B = metallic (R unused)
``normal_opengl.png``        tangent-space normal stored as (n + 1) / 2, linear; OpenGL
                             convention: +X to the image's right, +Y to the image's top
============================ =====================================================================
"""

from __future__ import annotations

import base64
import json
import math
import numbers
import os
import re
import struct
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any
from urllib.parse import quote

from ..errors import SVBRDFError
from ..plumbing import write_text

__all__ = ["DEFAULT_FILES", "write_gltf"]

#: The image file of each role when the writer is given none: the names the command lines write
#: (the table of the module doc), relative to the material file's folder.
DEFAULT_FILES = {
    "basecolor": "basecolor.png",
    "metallic": "metallic.png",
    "roughness": "roughness.png",
    "metallic_roughness": "metallic_roughness.png",
    "normal": "normal_opengl.png",
}

# The MIME type of each image suffix a material file may name.
_MIME_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
# A URI scheme ("http:", "file:") or a Windows drive ("C:"): not a relative file name.
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")


def material_path(path: str | os.PathLike, suffix: str, writer: str) -> Path:
    """``path`` as a Path, refused (one line) unless it ends in ``suffix`` and its folder exists."""
    path = Path(path)
    if path.suffix.lower() != suffix:
        raise SVBRDFError(
            f"{writer}: {path}: the file name must end in {suffix}; give a name like material{suffix}"
        )
    folder = path.parent
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise SVBRDFError(
            f"{writer}: {path}: its folder {folder} {what}; make the folder first or give another path"
        )
    return path


def image_names(writer: str, **names) -> dict[str, str]:
    """Each image name checked by :func:`_image_name`, by role."""
    return {role: _image_name(name, role, writer) for role, name in names.items()}


def _image_name(name: Any, role: str, writer: str) -> str:
    """``name`` checked as a relative file name of an image (see the module docstring)."""
    if isinstance(name, os.PathLike):
        name = os.fspath(name)
    if not isinstance(name, str):
        raise SVBRDFError(f"{writer}: {role}={name!r} is not a file name; give the image's file name as text")
    problem = None
    if not name.strip():
        problem = "is empty"
    elif any(ord(c) < 32 for c in name):
        problem = "holds a control character"
    elif "\\" in name:
        problem = "holds a backslash"
    elif name.startswith("/") or _SCHEME.match(name):
        problem = "is an absolute path or a URL, not a relative file name"
    elif any(part == "" for part in name.split("/")):
        problem = "has an empty folder name (a '//' or a trailing '/')"
    elif Path(name).suffix.lower() not in _MIME_TYPES:
        problem = "is not a .png, .jpg or .jpeg file"
    if problem:
        raise SVBRDFError(
            f"{writer}: {role}={name!r} {problem}; give the image's file name relative to the "
            f"material file's folder, with '/' between folders (e.g. '{role}.png')"
        )
    return name


# glTF enumerations (the specification's numeric codes)
_FLOAT, _UNSIGNED_SHORT = 5126, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_LINEAR, _LINEAR_MIPMAP_LINEAR, _REPEAT = 9729, 9987, 10497
_TRIANGLES = 4


def _generator() -> str:
    try:
        return f"svbrdf-render {metadata.version('svbrdf-render')}"
    except metadata.PackageNotFoundError:  # run from a source tree without installing
        return "svbrdf-render"


def _float32(x: float) -> float:
    """``x`` rounded to float32, as stored in the buffer (accessor min/max must match it)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _plane(size: float) -> tuple[bytes, list[dict], list[dict]]:
    """The buffer, buffer views and accessors of the square (positions, normals, tangents,
    texture coordinates, indices, in that order in the buffer)."""
    s = _float32(size)
    # corners: image top-left, top-right, bottom-right, bottom-left. glTF puts UV (0, 0) at the
    # image's top-left and v grows downwards, so the image's top edge is at y = +s.
    positions = [(-s, s, 0.0), (s, s, 0.0), (s, -s, 0.0), (-s, -s, 0.0)]
    uvs = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    normals = [(0.0, 0.0, 1.0)] * 4
    # tangent = +X (where u grows); w = +1 makes the bitangent cross(N, T) * w = +Y, the image's
    # top: a normal map's green channel then points up the image (OpenGL convention, as glTF).
    tangents = [(1.0, 0.0, 0.0, 1.0)] * 4
    indices = [0, 3, 2, 0, 2, 1]  # counter-clockwise seen from +Z: the front faces +Z
    parts = [
        (b"".join(struct.pack("<3f", *p) for p in positions), "VEC3", _FLOAT, _ARRAY_BUFFER),
        (b"".join(struct.pack("<3f", *n) for n in normals), "VEC3", _FLOAT, _ARRAY_BUFFER),
        (b"".join(struct.pack("<4f", *t) for t in tangents), "VEC4", _FLOAT, _ARRAY_BUFFER),
        (b"".join(struct.pack("<2f", *uv) for uv in uvs), "VEC2", _FLOAT, _ARRAY_BUFFER),
        (struct.pack("<6H", *indices), "SCALAR", _UNSIGNED_SHORT, _ELEMENT_ARRAY_BUFFER),
    ]
    buffer, views, accessors = b"", [], []
    for data, kind, component, target in parts:
        views.append({"buffer": 0, "byteOffset": len(buffer), "byteLength": len(data), "target": target})
        count = len(indices) if kind == "SCALAR" else len(positions)
        accessors.append(
            {"bufferView": len(views) - 1, "componentType": component, "count": count, "type": kind}
        )
        buffer += data  # every part is a multiple of 4 bytes long except the last: aligned
    accessors[0]["min"] = [-s, -s, 0.0]
    accessors[0]["max"] = [s, s, 0.0]
    return buffer, views, accessors


def _extras(extras: Any) -> dict | None:
    if extras is None:
        return None
    if not isinstance(extras, Mapping):
        raise SVBRDFError(
            f"write_gltf: extras must be a mapping (a JSON object), got {type(extras).__name__}"
        )
    try:
        return json.loads(json.dumps(dict(extras), allow_nan=False))
    except (TypeError, ValueError) as e:
        raise SVBRDFError(
            f"write_gltf: extras cannot be written as JSON ({e}); give text, numbers, lists and mappings"
        ) from None


def _check_name_and_size(writer: str, name: Any, size: Any) -> None:
    """The material's name is text; ``size`` (half the side, metres) a positive float32."""
    if not isinstance(name, str):
        raise SVBRDFError(f"{writer}: name={name!r} is not text; give the material's name as text")
    if isinstance(size, bool) or not isinstance(size, numbers.Real) or not math.isfinite(size) or size <= 0:
        raise SVBRDFError(f"{writer}: size={size!r} must be a positive finite number (half the side, metres)")
    if not 1e-30 < size < 1e30:  # stored as float32: far from its underflow and overflow
        raise SVBRDFError(f"{writer}: size={size!r} is out of float32 range; give a size in metres near 1")


def _gltf_material(name: str, extras: Mapping[str, Any] | None) -> dict[str, Any]:
    """The metallic-roughness material: every factor 1, textures 0, 1, 2 (see :func:`write_gltf`)."""
    material: dict[str, Any] = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "baseColorTexture": {"index": 0, "texCoord": 0},
            "metallicFactor": 1.0,
            "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": 1, "texCoord": 0},
        },
        "normalTexture": {"index": 2, "texCoord": 0, "scale": 1.0},
    }
    if (extra := _extras(extras)) is not None:
        material["extras"] = extra
    return material


def _gltf_document(
    name: str, material: dict, images: dict[str, str], buffer: bytes, views: list, accessors: list
) -> dict:
    """The glTF JSON: one scene, node and mesh (the plane of :func:`_plane`), the material, its
    images behind one sampler, and the buffer embedded as a data URI."""
    return {
        "asset": {"version": "2.0", "generator": _generator()},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": [{"name": name, "mesh": 0}],
        "meshes": [
            {
                "name": name,
                "primitives": [
                    {
                        "attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3},
                        "indices": 4,
                        "material": 0,
                        "mode": _TRIANGLES,
                    }
                ],
            }
        ],
        "materials": [material],
        "textures": [{"sampler": 0, "source": i} for i in range(len(images))],
        "samplers": [
            {"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _REPEAT, "wrapT": _REPEAT}
        ],
        "images": [
            {"name": role, "uri": quote(file, safe="/"), "mimeType": _MIME_TYPES[Path(file).suffix.lower()]}
            for role, file in images.items()
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [
            {
                "byteLength": len(buffer),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode("ascii"),
            }
        ],
    }


def write_gltf(
    path: str | os.PathLike,
    *,
    basecolor: str = DEFAULT_FILES["basecolor"],
    metallic_roughness: str = DEFAULT_FILES["metallic_roughness"],
    normal: str = DEFAULT_FILES["normal"],
    name: str = "svbrdf material",
    size: float = 1.0,
    extras: Mapping[str, Any] | None = None,
) -> Path:
    """Write a glTF 2.0 asset (``.gltf``): a square patch with the maps as its material.

    The scene holds one node with one mesh: a square of side ``2 * size`` centred at the
    origin in the plane z = 0, facing +Z (glTF's "up" is +Y, so a viewer shows it standing,
    facing the default camera). The image lies on it unflipped: its right edge is at x = +size,
    its top edge at y = +size. Attributes: POSITION, NORMAL (+Z), TANGENT (+X, w = +1, so the
    normal map's green channel points to the image's top: the OpenGL convention glTF uses)
    and TEXCOORD_0 (glTF puts UV (0, 0) at the image's top-left corner, so the vertex at
    (-size, +size) has UV (0, 0)), and 16-bit indices of two triangles. The buffer is embedded
    as a base64 data URI: the asset is this one file plus the images.

    The material is metallic-roughness PBR with every factor 1: ``baseColorTexture`` (sRGB, as
    glTF requires), ``metallicRoughnessTexture`` (linear; G = roughness, B = metallic) and
    ``normalTexture`` (scale 1). All three share one sampler: linear magnification, trilinear
    minification (linear within and between mipmaps), repeat wrapping so that a tileable map
    tiles when the UVs are scaled. Images are referenced by relative URI (percent-encoded where
    a file name needs it) with their MIME type.

    Args:
        path: the file to write, ending in ``.gltf``; its folder must exist.
        basecolor, metallic_roughness, normal: the images' file names relative to ``path``'s
            folder (``.png``, ``.jpg`` or ``.jpeg``).
        name: the material's, mesh's and node's name.
        size: half the side of the square, in metres (glTF's unit); positive.
        extras: JSON-compatible data stored as the material's ``extras`` (e.g. the model that
            predicted the maps).

    Returns:
        ``path``. Raises :class:`~svbrdf_render.errors.SVBRDFError` on a bad argument and
        :class:`~svbrdf_render.errors.OutputError` when the file cannot be written.
    """
    writer = "write_gltf"
    path = material_path(path, ".gltf", writer)
    images = image_names(writer, basecolor=basecolor, metallic_roughness=metallic_roughness, normal=normal)
    _check_name_and_size(writer, name, size)
    document = _gltf_document(name, _gltf_material(name, extras), images, *_plane(float(size)))
    return write_text(path, json.dumps(document, indent=2) + "\n")
