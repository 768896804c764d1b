"""The material folder: what ``predict`` writes for one photo, ready for texture tools.

One folder per photo, written whole or not at all (staged in a temporary folder beside it,
then moved in), with every image saying its encoding inside the file (PNG colour chunks,
:func:`svbrdf_render.write_image`) and in ``material.json``:

==========================  ========  ===========================================================
file                        encoding  holds
==========================  ========  ===========================================================
``basecolor.png``           sRGB      metal/rough base colour (:mod:`svbrdf_render.metalrough`)
``metallic.png``            linear    metalness, grey
``roughness.png``           linear    perceptual roughness, grey; GGX alpha = roughness^2
``metallic_roughness.png``  linear    glTF's packing: G roughness, B metallic (R 0)
``normal.png``              linear    tangent-space normal stored (n+1)/2; OpenGL (+Y up) unless
                                      ``directx`` (green flipped); then ``normal_opengl.png``
                                      too, for the material files
``diffuse.png``             sRGB      the project's diffuse albedo (``linear``: as Des18 stores it)
``specular.png``            sRGB      the project's specular albedo (F0), encoded like diffuse
``*.exr``                   linear    with ``exr``: the same maps as half floats
``material.json``                     this table, conventions, BRDF, model, refinement, provenance
``material.gltf``                     glTF 2.0: a textured plane, metal/rough PBR material
``material.mtlx``                     MaterialX document of the same material
``index.html``                        viewer: the material under a light that follows the mouse
``input.png``, ``rerender.png``, ``relit.gif``: the photo's square, its re-rendering, a relit preview
==========================  ========  ===========================================================

A folder that already holds another material (a ``material.json`` of another photo, or maps
and no ``material.json``) is refused before any work (:func:`check_material_folder`): rerunning
the same photo replaces its own files and leaves anything else there alone.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import shutil
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import SVBRDF, encode_normal, linear_to_srgb, write_image
from svbrdf_render.formats.files import (
    atomic_output,
    locked,
    replace_folder,
    temporary_path,
    write_failure,
    write_text,
)

from ..errors import DataError

__all__ = [
    "MATERIAL_FILES",
    "MATERIAL_FORMAT",
    "MaterialContent",
    "check_material_folder",
    "model_record",
    "photo_sha256",
    "to_directx",
    "write_gif",
    "write_material",
]

MATERIAL_FORMAT = "svbrdf-material"
MATERIAL_VERSION = 1

#: Every file name a material folder may hold (what a rerun replaces).
MATERIAL_FILES = (
    "basecolor.png", "metallic.png", "roughness.png", "metallic_roughness.png", "normal.png",
    "normal_opengl.png", "diffuse.png", "specular.png", "basecolor.exr", "metallic.exr",
    "roughness.exr", "normal.exr", "diffuse.exr", "specular.exr", "material.json", "material.gltf",
    "material.mtlx", "index.html", "input.png", "rerender.png", "relit.gif", "relit.png",
)  # fmt: skip
_MAP_FILES = ("normal.png", "diffuse.png", "roughness.png", "specular.png", "basecolor.png")

_NORMAL_NOTES = {
    "opengl": "svbrdf normal map: tangent space, OpenGL convention (+X right, +Y up = image top), "
    "stored (n+1)/2, linear",
    "directx": "svbrdf normal map: tangent space, DirectX convention (+X right, +Y down = green "
    "flipped), stored (n+1)/2, linear",
}

#: What material.json says about the BRDF the maps are for.
BRDF = {
    "model": "des18",
    "formula": "f = d (1 - s) / pi + F(v.h) D(n.h) V / 4",
    "distribution": "GGX, alpha = 0.001 + 0.999 roughness^2",
    "masking": "Schlick-GGX, k = alpha / 2",
    "fresnel": "Schlick, spherical-Gaussian form, F0 = specular",
    "metal_rough": "glTF 2.0 metal/rough: F0 = mix(0.04, basecolor, metallic), diffuse colour "
    "basecolor (1 - metallic); converted from diffuse/specular by svbrdf_render.metalrough",
}


def to_directx(normal: Tensor) -> Tensor:
    """OpenGL (y up, the project's convention) normals ``(B, 3, H, W)`` to DirectX (y down): y negated.

    Its own inverse. Stored as ``(n + 1) / 2``, this is the green channel ``g -> 1 - g``.
    """
    return normal * normal.new_tensor([1.0, -1.0, 1.0]).view(1, 3, 1, 1)


def photo_sha256(path) -> str:
    """The SHA-256 of the photo file: the material's identity in ``material.json``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def check_material_folder(folder, photo: Path, flag: str = "-o", *, sha256: str | None = None) -> None:
    """Refuse (:class:`DataError`, exit 2) a folder that holds another material than ``photo``'s:
    a ``material.json`` naming another photo (by SHA-256, ``sha256`` when known), an unreadable
    one, or maps with no ``material.json``. A missing or empty folder, or one of the same photo,
    passes."""
    folder = Path(folder)
    if folder.is_symlink():  # it would write through the link, outside the output folder
        raise DataError(
            f"{folder}: is a symbolic link (to {os.readlink(folder)}), so the material would be "
            f"written outside {flag}; remove the link or choose another {flag}"
        )
    if not folder.is_dir():
        return
    record = folder / "material.json"
    if record.is_file():
        data = _read_json(record)
        if data is None or data.get("format") != MATERIAL_FORMAT:
            raise DataError(
                f"{flag} {folder}: its material.json is not an svbrdf material record; choose "
                "another output folder or remove it"
            )
        theirs = (data.get("photo") or {}).get("sha256")
        if theirs != (sha256 or photo_sha256(photo)):
            named = (data.get("photo") or {}).get("file") or "another photo"
            raise DataError(
                f"{flag} {folder}: holds the material of {named}, not of {photo}; choose another "
                "output folder or remove that one"
            )
        return
    maps = [name for name in _MAP_FILES if (folder / name).exists()]
    if maps:
        raise DataError(
            f"{flag} {folder}: holds maps ({', '.join(maps)}) with no material.json, another "
            "material; choose another output folder or remove them"
        )


@dataclass(frozen=True)
class MaterialContent:
    """What goes into a material folder besides the maps.

    Attributes:
        photo: the photo's square the maps are of, ``(3, H, W)`` linear.
        figure: rerender.png, display values.
        relit: ``(n, 3, H, W)`` linear frames for relit.gif, ``(3, H, W)`` display values for
            relit.png, or None.
        record: material.json's fields that the capture knows (photo, model, refinement...).
    """

    photo: Tensor
    figure: Tensor
    relit: Tensor | None
    record: dict


#: Maps that get an OpenEXR copy with ``exr`` (linear values; the normal stored as in its PNG).
_EXR_MAPS = ("basecolor", "metallic", "roughness", "normal", "diffuse", "specular")


@dataclass(frozen=True)
class _Map:
    stem: str
    stored: Tensor  # (C, H, W) the PNG's values
    encoding: str
    holds: str
    linear: Tensor  # (C, H, W) the same map's linear values (its EXR copy)


def _maps(svbrdf: SVBRDF, options) -> list[_Map]:
    """Every map of the folder, in the encodings ``options`` ask for."""
    from svbrdf_render.metalrough import to_metal_rough

    svbrdf = svbrdf.detach().to("cpu", torch.float32)
    mr = to_metal_rough(svbrdf)
    normal = svbrdf.normal
    stored = encode_normal((to_directx(normal) if options.normal_convention == "directx" else normal)[0])
    albedo = options.albedo_encoding
    encode = linear_to_srgb if albedo == "srgb" else (lambda x: x)
    base, metal, rough = mr.basecolor[0], mr.metallic[0], svbrdf.roughness[0]
    packed = torch.cat([torch.zeros_like(metal), mr.roughness[0], metal])
    maps = [
        _Map("basecolor", linear_to_srgb(base), "srgb", "metal/rough base colour", base),
        _Map("metallic", metal, "linear", "metalness", metal),
        _Map("roughness", rough, "linear", "perceptual roughness (GGX alpha = roughness^2)", rough),
        _Map("metallic_roughness", packed, "linear", "glTF packing: G roughness, B metallic", packed),
        _Map("normal", stored, "linear", f"tangent-space normal, {options.normal_convention}", stored),
        _Map("diffuse", encode(svbrdf.diffuse[0]), albedo, "diffuse albedo (des18)", svbrdf.diffuse[0]),
        _Map("specular", encode(svbrdf.specular[0]), albedo, "specular albedo, F0 (des18)",
             svbrdf.specular[0]),
    ]  # fmt: skip
    if options.normal_convention == "directx":
        gl = encode_normal(normal[0])
        maps.append(_Map("normal_opengl", gl, "linear", "tangent-space normal, opengl", gl))
    return maps


def _write_all(stage: Path, svbrdf: SVBRDF, content: MaterialContent, options) -> dict:
    """Every file of the material into ``stage``; returns material.json's content."""
    from svbrdf_render.formats.mapfiles import write_exr
    from svbrdf_render.formats.materialfiles import write_gltf, write_materialx
    from svbrdf_render.viewer import write_viewer

    bits = options.bits
    files: dict[str, dict] = {}
    for m in _maps(svbrdf, options):
        convention = options.normal_convention if m.stem == "normal" else "opengl"
        note = _NORMAL_NOTES[convention] if m.stem.startswith("normal") else f"svbrdf {m.holds}, {m.encoding}"
        write_image(stage / f"{m.stem}.png", m.stored, bits=bits, encoding=m.encoding, note=note)
        files[m.stem] = {"file": f"{m.stem}.png", "encoding": m.encoding, "bits": bits,
                         "channels": int(m.stored.shape[0]), "holds": m.holds}  # fmt: skip
        if options.exr and m.stem in _EXR_MAPS:
            write_exr(stage / f"{m.stem}.exr", m.linear)
            files[f"{m.stem}_exr"] = {"file": f"{m.stem}.exr", "encoding": "linear", "bits": "half float",
                                      "channels": int(m.linear.shape[0]), "holds": m.holds}  # fmt: skip
    write_image(stage / "input.png", linear_to_srgb(content.photo), bits=bits, encoding="srgb",
                note="svbrdf: the square of the photo the maps are of")  # fmt: skip
    write_image(stage / "rerender.png", content.figure, encoding="srgb")
    if options.relit == "gif":
        write_gif(stage / "relit.gif", content.relit)
    elif options.relit == "png":
        write_image(stage / "relit.png", content.relit, encoding="srgb")
    gl_normal = "normal_opengl.png" if options.normal_convention == "directx" else "normal.png"
    name = content.record.get("name") or "svbrdf material"
    write_gltf(stage / "material.gltf", basecolor="basecolor.png", normal=gl_normal,
               metallic_roughness="metallic_roughness.png", name=name,
               extras={"svbrdf": "material.json"})  # fmt: skip
    write_materialx(stage / "material.mtlx", basecolor="basecolor.png", metallic="metallic.png",
                    roughness="roughness.png", normal=gl_normal, name=_mtlx_name(name))  # fmt: skip
    flash = content.record.get("flash") or {}
    intensity = flash.get("intensity")
    write_viewer(stage / "index.html", svbrdf.detach().to("cpu", torch.float32), title=name,
                 intensity=intensity if isinstance(intensity, (int, float)) and intensity > 0 else None,
                 light=_above(flash.get("position")), shots=_shot_lights(content.record))  # fmt: skip
    record = {
        "format": MATERIAL_FORMAT,
        "version": MATERIAL_VERSION,
        **content.record,
        "maps": files,
        "normal": {
            "convention": options.normal_convention,
            "space": "tangent space of the plane: +X image right, +Y image up (opengl; directx: "
            "down), +Z out of the surface",
            "stored": "(n + 1) / 2 per channel",
        },
        "units": {
            "patch": "the maps span a square of side 2 (x, y in [-1, 1], z = 0 the surface)",
            "values": "maps in [0, 1]; albedos are reflectances, roughness is perceptual",
        },
        "brdf": BRDF,
        "files": {"gltf": "material.gltf", "materialx": "material.mtlx", "viewer": "index.html",
                  "input": "input.png", "rerender": "rerender.png",
                  "relit": {"gif": "relit.gif", "png": "relit.png"}.get(options.relit)},  # fmt: skip
    }
    write_text(stage / "material.json", json.dumps(record, indent=2) + "\n")
    return record


def write_gif(path: Path, frames: Tensor, ms: int = 80) -> Path:
    """``frames`` (linear, ``(N, 3, H, W)``) as a looping GIF. One palette for every frame, built
    from all of them (every 4th pixel): a palette per frame (Pillow's default) took 1.5 s of a
    256 px capture's 4.7 s, and flickered between frames."""
    import numpy as np
    from PIL import Image

    pixels = (linear_to_srgb(frames) * 255).round().byte().permute(0, 2, 3, 1).numpy()
    montage = Image.fromarray(np.ascontiguousarray(np.concatenate([p[::4, ::4] for p in pixels])))
    palette = montage.quantize(256, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(p).quantize(palette=palette) for p in pixels]
    with atomic_output(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=ms, loop=0)
    return path


def _mtlx_name(name: str) -> str:
    """A MaterialX element name (ASCII letters, digits, underscores, not starting with a digit):
    accents dropped (``café`` -> ``cafe``), every other character an underscore, and
    ``material`` for a name with no ASCII letter or digit left (``фото``)."""
    folded = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode("ascii")
    cleaned = "".join(c if c.isalnum() else "_" for c in folded)
    if not any(c.isalnum() for c in cleaned):
        cleaned = "material"
    return cleaned if not cleaned[0].isdigit() else f"m_{cleaned}"


def _above(position) -> list[float] | None:
    """``position`` when it is three finite numbers with ``z > 0`` (a light the viewer can
    start at: where the photo's flash was), else None (the viewer's camera flash)."""
    import math

    if not isinstance(position, (list, tuple)) or len(position) != 3:
        return None
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in position) or position[2] <= 0:
        return None
    return [float(v) for v in position]


def _shot_lights(record: dict) -> list:
    """``[(name, light position)]`` of the shots a capture of several photos records (each
    shot's ``light``), for the viewer's keys 1-9."""
    shots = []
    for i, shot in enumerate(record.get("shots") or []):
        light = _above(shot.get("light") if isinstance(shot, dict) else None)
        if light is not None:
            shots.append((str(shot.get("file") or f"shot {i + 1}"), light))
    return shots


def write_material(folder, svbrdf: SVBRDF, content: MaterialContent, options) -> dict:
    """Write the material folder of one photo (see the module): staged in ``.NAME.PID.tmp``
    beside ``folder``, then moved in, so an error or an interrupt leaves ``folder`` as it was.

    ``svbrdf``: the final maps (one sample, linear, OpenGL normals); ``options``: a
    :class:`~svbrdf_models.capture.one.CaptureOptions`. Returns material.json's content.
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    stage = temporary_path(folder)
    stage.mkdir()
    try:
        record = _write_all(stage, svbrdf, content, options)
        photo = record["photo"]
        # The check and the move are one step: another capture into the same folder (a second
        # command on a photo of the same name) waits here, then finds this material.
        with locked(folder.parent):
            check_material_folder(folder, Path(photo["file"]), sha256=photo["sha256"])
            try:
                _move_in(stage, folder)
            except OSError as e:
                raise write_failure(folder, e) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return record


def _move_in(stage: Path, folder: Path) -> None:
    """``stage`` in the place of ``folder`` as a whole (:func:`replace_folder`): a reader, or a
    crash, sees the old material or the new one, never both; files of an earlier run of the
    same photo that this one did not write go, files a user put in the folder stay."""
    replace_folder(stage, folder, keep=MATERIAL_FILES)


def model_record(predictor) -> dict:
    """material.json's ``model``: the source (as text), SHA-256, resolution and training steps of
    the network that made a material."""
    model = {key: getattr(predictor, key, None) for key in ("source", "sha256", "resolution")}
    model["steps"] = getattr(predictor, "steps", getattr(predictor, "step", None))
    return {k: (str(v) if k == "source" and v is not None else v) for k, v in model.items()}


def provenance() -> dict:
    """The versions of the packages and the time that made a material."""
    import svbrdf_render

    from .. import __version__

    return {
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "svbrdf_render": svbrdf_render.__version__,
        "svbrdf_models": __version__,
        "torch": torch.__version__,
    }
