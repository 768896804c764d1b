"""material.json, the material record: what a material folder says about itself, built here.

Its fields, in the order the file holds them (:func:`material_record`):

- ``format`` and ``version`` (:data:`MATERIAL_FORMAT`, :data:`MATERIAL_VERSION`);
- what the capture knows: of one photo, :func:`photo_record` (the photo, the model, the
  refinement, the flash, where the camera stood, the provenance); of several shots or a
  calibrated set, their modules' own (:mod:`~svbrdf_models.capture.shotcapture`,
  :mod:`~svbrdf_models.capture.calibrated`), from the same :func:`model_record` and
  :func:`provenance`;
- the folder's own: each map written with its encoding and what it holds, the normal
  convention, the units, the BRDF the maps are for, and the other files, as the folder's
  declaration (:data:`svbrdf_models.capture.material.FOLDER`) says.

The folder and the writing of its files are :mod:`svbrdf_models.capture.material`'s.
"""

from __future__ import annotations

import datetime
import hashlib
from pathlib import Path

import torch

__all__ = [
    "BRDF",
    "MATERIAL_FORMAT",
    "MATERIAL_VERSION",
    "material_record",
    "model_record",
    "photo_record",
    "photo_sha256",
    "provenance",
]

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


def photo_record(predictor, path: Path, options, entry: dict, geometry) -> dict:
    """material.json's fields that a capture of one photo knows (its summary ``entry``, the
    camera's ``geometry``): the photo, the model, the refinement, the flash, the provenance."""
    from .photos import photo_encoding

    return {
        "name": path.stem,
        "photo": {"file": path.name, "sha256": photo_sha256(path), "square": entry["square"],
                  "crop": list(options.crop) if options.crop else None,
                  "encoding": photo_encoding(path, options.linear)},  # fmt: skip
        "model": model_record(predictor),
        "maps_size": entry["maps"],
        "tiles": entry["tiles"],
        "rerender_rmse": entry["rmse"],
        "flash": entry["flash"],
        "refine": entry["refine"] or {"budget": 0},
        "tileable": entry["tileable"],
        "reference": entry.get("reference"),
        "metal": options.metal,
        "geometry": geometry.record(used=bool(options.refine) and options.scene is None),
        "provenance": provenance(),
    }


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
