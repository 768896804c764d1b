"""The material folder: what ``predict`` writes for one photo, ready for texture tools.

One folder per photo, written whole or not at all (staged in a temporary folder beside it,
then moved in), with every image saying its encoding inside the file (PNG colour chunks,
:func:`svbrdf_render.write_image`) and in ``material.json``.

The files are declared once, in :data:`FOLDER` (name, encoding, what it holds, when it is
written, where material.json lists it, its writer): the writer (:func:`write_material`) writes
exactly the files declared for the options given, and material.json's lists, the ``predict
--help`` listing and docs/capture.md's table (:mod:`svbrdf_models.capture.batch`) are made from
it. A new file is an entry and its writer here, and the docs table printed again.

material.json, what the folder says about itself, is written last (:func:`material_record`):
``format`` and ``version``; what the capture knows (the photo, the model, the refinement, the
flash, where the camera stood: each capture module's own, :mod:`~svbrdf_models.capture.one`'s,
:mod:`~svbrdf_models.capture.shotcapture`'s, :mod:`~svbrdf_models.capture.calibrated`'s, from
the same :func:`model_record` and :func:`provenance`); then the folder's own: each map written
with its encoding and what it holds, the normal convention, the units, the BRDF the maps are
for, and the other files.

A folder that holds another material (a ``material.json`` of another photo, or maps and no
``material.json``) is refused (:func:`check_material_folder`) by the command before the model
loads and by the writer, where the check and the move are one step under a lock. Rerunning the
same photo replaces its own files and leaves anything else there alone.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import SVBRDF, encode_normal, linear_to_srgb, write_image
from svbrdf_render.formats.mapfiles import write_gif
from svbrdf_render.plumbing import locked, replace_folder, temporary_path, write_failure, write_text

from ..errors import DataError

__all__ = [
    "BRDF", "FOLDER", "FolderFile", "MATERIAL_FILES", "MATERIAL_FORMAT", "MATERIAL_VERSION",
    "MaterialContent", "WHEN", "check_material_folder", "material_record", "model_record", "photo_sha256",
    "provenance", "to_directx", "write_material", "written",
]  # fmt: skip

_NORMAL_NOTES = {
    "opengl": "svbrdf normal map: tangent space, OpenGL convention (+X right, +Y up = image top), "
    "stored (n+1)/2, linear",
    "directx": "svbrdf normal map: tangent space, DirectX convention (+X right, +Y down = green "
    "flipped), stored (n+1)/2, linear",
}


def to_directx(normal: Tensor) -> Tensor:
    """OpenGL (y up, the project's convention) normals ``(B, 3, H, W)`` to DirectX (y down): y negated.

    Its own inverse. Stored as ``(n + 1) / 2``, this is the green channel ``g -> 1 - g``.
    """
    return normal * normal.new_tensor([1.0, -1.0, 1.0]).view(1, 3, 1, 1)


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
        try:
            data = json.loads(record.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            data = None
        if not isinstance(data, dict) or data.get("format") != MATERIAL_FORMAT:
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


@dataclass(frozen=True)
class _Map:
    stored: Tensor  # (C, H, W) the PNG's values
    linear: Tensor  # (C, H, W) the same map's linear values (its EXR copy)


def _maps(svbrdf: SVBRDF, options) -> dict[str, _Map]:
    """The values of every map of the folder by name, in the normal convention ``options`` ask for
    (the albedos linear: their PNGs encode them as declared)."""
    from svbrdf_render.metalrough import to_metal_rough

    svbrdf = svbrdf.detach().to("cpu", torch.float32)
    mr = to_metal_rough(svbrdf)
    normal = svbrdf.normal
    stored = encode_normal((to_directx(normal) if options.normal_convention == "directx" else normal)[0])
    base, metal = mr.basecolor[0], mr.metallic[0]
    packed = torch.cat([torch.zeros_like(metal), mr.roughness[0], metal])
    gl = encode_normal(normal[0])
    return {
        "basecolor": _Map(linear_to_srgb(base), base), "metallic": _Map(metal, metal),
        "roughness": _Map(svbrdf.roughness[0], svbrdf.roughness[0]),
        "metallic_roughness": _Map(packed, packed), "normal": _Map(stored, stored),
        "diffuse": _Map(svbrdf.diffuse[0], svbrdf.diffuse[0]),
        "specular": _Map(svbrdf.specular[0], svbrdf.specular[0]), "normal_opengl": _Map(gl, gl),
    }  # fmt: skip


@dataclass
class _Made:
    """What the writers of one folder share; ``listed``: material.json's entries of the maps written."""

    svbrdf: SVBRDF
    content: MaterialContent
    options: object  # a CaptureOptions
    maps: dict[str, _Map]
    listed: dict[str, dict] = field(default_factory=dict)
    record: dict | None = None

    def encoding(self, f: FolderFile) -> str:
        """The encoding ``f`` is written in for these options."""
        return self.options.albedo_encoding if f.encoding == "albedo" else f.encoding

    def holds(self, f: FolderFile) -> str:
        """What ``f`` holds, the normal convention of these options said."""
        return f.holds.format(normal=self.options.normal_convention)


def _png_map(path: Path, f: FolderFile, made: _Made) -> dict:
    """A map's PNG, its encoding and what it holds told in the file (a normal: its convention)."""
    m, encoding, holds, bits = made.maps[path.stem], made.encoding(f), made.holds(f), made.options.bits
    stored = linear_to_srgb(m.stored) if f.encoding == "albedo" and encoding == "srgb" else m.stored
    if path.stem.startswith("normal"):
        note = _NORMAL_NOTES[made.options.normal_convention if path.stem == "normal" else "opengl"]
    else:
        note = f"svbrdf {holds}, {encoding}"
    write_image(path, stored, bits=bits, encoding=encoding, note=note)
    return {"file": f.name, "encoding": encoding, "bits": bits, "channels": int(stored.shape[0]),
            "holds": holds}  # fmt: skip


def _exr_map(path: Path, f: FolderFile, made: _Made) -> dict:
    """A map's OpenEXR copy: its linear values (the normal as stored) in half floats."""
    from svbrdf_render.formats.mapfiles import write_exr

    m = made.maps[path.stem]
    write_exr(path, m.linear)
    return {"file": f.name, "encoding": "linear", "bits": "half float", "channels": int(m.linear.shape[0]),
            "holds": made.holds(f)}  # fmt: skip


def _image(path: Path, f: FolderFile, made: _Made) -> None:
    """input.png (the photo's square, linear: encoded and noted), rerender.png or relit.png
    (display values, as they are)."""
    if path.stem == "input":
        write_image(path, linear_to_srgb(made.content.photo), bits=made.options.bits, encoding=f.encoding,
                    note=f"svbrdf: {f.holds}")  # fmt: skip
    else:
        shown = made.content.figure if path.stem == "rerender" else made.content.relit
        write_image(path, shown, encoding=f.encoding)


def _gif(path: Path, f: FolderFile, made: _Made) -> None:
    write_gif(path, made.content.relit)


def _gl_normal(made: _Made) -> str:
    """The OpenGL normal map the material files take (glTF and MaterialX know no other)."""
    return "normal_opengl.png" if made.options.normal_convention == "directx" else "normal.png"


def _gltf(path: Path, f: FolderFile, made: _Made) -> None:
    from svbrdf_render.formats import write_gltf

    write_gltf(path, basecolor="basecolor.png", normal=_gl_normal(made),
               metallic_roughness="metallic_roughness.png", name=_name(made),
               extras={"svbrdf": "material.json"})  # fmt: skip


def _mtlx(path: Path, f: FolderFile, made: _Made) -> None:
    from svbrdf_render.formats import materialx_name, write_materialx

    write_materialx(path, basecolor="basecolor.png", metallic="metallic.png", roughness="roughness.png",
                    normal=_gl_normal(made), name=materialx_name(_name(made)))  # fmt: skip


def _viewer(path: Path, f: FolderFile, made: _Made) -> None:
    from svbrdf_render.viewer import write_viewer

    flash = made.content.record.get("flash") or {}
    intensity = flash.get("intensity")
    write_viewer(path, made.svbrdf.detach().to("cpu", torch.float32), title=_name(made),
                 intensity=intensity if isinstance(intensity, (int, float)) and intensity > 0 else None,
                 light=_above(flash.get("position")), shots=_shot_lights(made.content.record))  # fmt: skip


def _name(made: _Made) -> str:
    return made.content.record.get("name") or "svbrdf material"


def _record(path: Path, f: FolderFile, made: _Made) -> None:
    """material.json, the last file (:func:`material_record`): the
    capture's fields, the maps written, and every other file it lists (None: not written)."""
    others, now = [g for g in FOLDER if g.listed.startswith("files.")], written(made.options)
    files = {g.listed.removeprefix("files."): None for g in others}
    files.update({g.listed.removeprefix("files."): g.name for g in others if g in now})
    made.record = material_record(made.content.record, made.listed, files, made.options.normal_convention)
    write_text(path, json.dumps(made.record, indent=2) + "\n")


@dataclass(frozen=True)
class FolderFile:
    """One file of the material folder, as :data:`FOLDER` declares it.

    Attributes:
        name: the file's name in the folder.
        encoding: how the image stores its values: ``"srgb"``, ``"linear"``, ``"albedo"`` (as
            the options' ``albedo_encoding`` says), or ``""`` for a file that is no image.
        holds: what it holds: a map's ``holds`` in material.json and its PNG's note;
            ``{normal}`` stands for the normal convention.
        when: the key of :data:`WHEN` that says when it is written.
        listed: where material.json lists it (``maps.KEY``, ``files.KEY``; ``""``: material.json).
        make: its writer, ``make(path, file, made)``: material.json's entry of a map, else None.
    """

    name: str
    encoding: str
    holds: str
    when: str
    listed: str
    make: Callable[[Path, FolderFile, _Made], dict | None]


#: When a file is written: the options' words (help, docs) and the test of the options.
WHEN: dict[str, tuple[str, Callable[[object], bool]]] = {
    "always": ("always", lambda o: True),
    "exr": ("--exr", lambda o: o.exr),
    "dx": ("--normal dx", lambda o: o.normal_convention == "directx"),
    "gif": ("--relit gif (default)", lambda o: o.relit == "gif"),
    "png": ("--relit png", lambda o: o.relit == "png"),
}


def _map(stem: str, encoding: str, holds: str, exr: bool = True) -> tuple[FolderFile, ...]:
    """A map's PNG and, with ``exr``, its OpenEXR copy (linear half floats, the normal as stored)."""
    png = FolderFile(f"{stem}.png", encoding, holds, "always", f"maps.{stem}", _png_map)
    copy = FolderFile(f"{stem}.exr", "linear", holds, "exr", f"maps.{stem}_exr", _exr_map)
    return (png, copy) if exr else (png,)


#: The material folder, every file it may hold, in the order they are written (material.json
#: last: it lists the others).
FOLDER: tuple[FolderFile, ...] = (
    *_map("basecolor", "srgb", "metal/rough base colour"),
    *_map("metallic", "linear", "metalness"),
    *_map("roughness", "linear", "perceptual roughness (GGX alpha = roughness^2)"),
    *_map("metallic_roughness", "linear", "glTF packing: G roughness, B metallic", exr=False),
    *_map("normal", "linear", "tangent-space normal, {normal}"),
    *_map("diffuse", "albedo", "diffuse albedo (des18)"),
    *_map("specular", "albedo", "specular albedo, F0 (des18)"),
    FolderFile("normal_opengl.png", "linear", "tangent-space normal, opengl", "dx", "maps.normal_opengl",
               _png_map),
    FolderFile("material.gltf", "", "glTF 2.0: a square plane of side 2 facing +Z, metal/rough material, "
               "repeat sampler", "always", "files.gltf", _gltf),
    FolderFile("material.mtlx", "", "MaterialX 1.38 document of the same material (gltf_pbr shader)",
               "always", "files.materialx", _mtlx),
    FolderFile("index.html", "", "the viewer: the material under a light that follows the mouse (no network)",
               "always", "files.viewer", _viewer),
    FolderFile("input.png", "srgb", "the square of the photo the maps are of", "always", "files.input",
               _image),
    FolderFile("rerender.png", "srgb", "photo | re-rendering under the fitted flash | |error| heat map; "
               "refined: the network's and the refined maps', one flash", "always", "files.rerender", _image),
    FolderFile("relit.gif", "srgb", "a point light circling the material", "gif", "files.relit", _gif),
    FolderFile("relit.png", "srgb", "the relit frames as a grid (refined: a row per version)", "png",
               "files.relit", _image),
    FolderFile("material.json", "", "the maps with their encodings, normal convention, units, BRDF, "
               "model (source, sha256, steps), refinement (budget, steps, seconds, RMSEs), photo (name, "
               "sha256, crop), geometry (where the camera stood, and from what), flash (where, how it was "
               "placed, the highlight found), metal, seam errors, package versions, time", "always", "",
               _record),
)  # fmt: skip

#: Every file name a material folder may hold (what a rerun replaces).
MATERIAL_FILES = tuple(f.name for f in FOLDER)
#: The maps whose presence marks a material (with or without its material.json).
_MAP_FILES = tuple(f.name for f in FOLDER if f.listed.startswith("maps.") and f.name.endswith(".png"))


def written(options) -> list[FolderFile]:
    """The files of :data:`FOLDER` a capture with ``options`` writes, in order."""
    return [f for f in FOLDER if WHEN[f.when][1](options)]


def _write_all(stage: Path, svbrdf: SVBRDF, content: MaterialContent, options) -> dict:
    """Each file :data:`FOLDER` declares for ``options`` into ``stage``, by its writer; returns
    material.json's content."""
    made = _Made(svbrdf, content, options, _maps(svbrdf, options))
    for f in written(options):
        entry = f.make(stage / f.name, f, made)
        if entry is not None:
            made.listed[f.listed.partition(".")[2]] = entry
    return made.record


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


# -- material.json: the record of the material, built from the capture's fields -----------------

MATERIAL_FORMAT = "svbrdf-material"
MATERIAL_VERSION = 1

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

#: What material.json says of the normal map's space, and of the units of the maps.
_NORMAL_SPACE = {
    "space": "tangent space of the plane: +X image right, +Y image up (opengl; directx: down), +Z out of "
    "the surface",
    "stored": "(n + 1) / 2 per channel",
}
_UNITS = {
    "patch": "the maps span a square of side 2 (x, y in [-1, 1], z = 0 the surface)",
    "values": "maps in [0, 1]; albedos are reflectances, roughness is perceptual",
}


def material_record(capture: dict, maps: dict[str, dict], files: dict[str, str | None],
                    convention: str) -> dict:  # fmt: skip
    """material.json's content: the format, the ``capture``'s fields, then the folder's own: the
    ``maps`` written (material.json's entry of each), the normal ``convention``, the units, the
    BRDF and the other ``files`` (None for one not written)."""
    return {
        "format": MATERIAL_FORMAT,
        "version": MATERIAL_VERSION,
        **capture,
        "maps": maps,
        "normal": {"convention": convention, **_NORMAL_SPACE},
        "units": dict(_UNITS),
        "brdf": dict(BRDF),
        "files": files,
    }


def photo_sha256(path) -> str:
    """The SHA-256 of the photo file: the material's identity in ``material.json``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
