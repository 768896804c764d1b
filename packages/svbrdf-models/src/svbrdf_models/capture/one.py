"""Capture: from a real flash photo to maps a material artist can use.

The pieces of ``svbrdf-models predict`` (and ``svbrdf-train predict``), each usable alone::

    from svbrdf_models.capture import CaptureOptions, capture_one, flash_consistency, load_photo, tile_predict
    photo, notes = load_photo("shot.jpg")              # EXIF-oriented, centre square, linear
    svbrdf = model.predict(photo)                       # maps at the model's resolution
    svbrdf = model.predict(photo, refine=100)           # refined at the square's own resolution
    svbrdf = tile_predict(model.predict, photo, model.resolution)  # or tiles at full size
    fit = flash_consistency(svbrdf, photo)              # re-render under the fitted flash
    entry = capture_one(model, "shot.jpg", "maps/shot", CaptureOptions(refine=100))  # all, written

It needs svbrdf-render and this package only (Pillow through ``svbrdf-models[photo]``, which is
``svbrdf-render[io]``): no training code, no tracking.

The steps live in modules of their own, each the one address of its names (the public ones are
stated by :mod:`svbrdf_models.capture`): reading and judging photos
(:mod:`svbrdf_models.capture.photos`: what is refused, what is noted), tiles and their memory
cost (:mod:`svbrdf_models.capture.tiles`), the flash fit and the relit preview
(:mod:`svbrdf_models.capture.relight`), the material folder (:mod:`svbrdf_models.capture.material`).
This module holds the options (:class:`CaptureOptions`, where every rule about which options go
together is written) and runs the steps for one photo (:func:`capture_one`: with refinement, maps
asked smaller than :data:`svbrdf_render.MIN_REFINE_SIDE` are refused; a square smaller than the
model's resolution is noted, upsampled); a batch's ``summary.json`` is written by
:mod:`svbrdf_models.capture.batch`.
"""

from __future__ import annotations

import importlib.util
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import MAP_NAMES, MIN_REFINE_SIDE, SVBRDF, Refinement, Scene

from ..errors import DataError
from .figures import rerender_figure
from .geometry import CaptureGeometry, capture_geometry, place_flash, record_flash
from .photos import PhotoError, load_photo, square_photo
from .reference import Reference
from .refining import (
    BACKEND,
    FULL,
    as_dielectric,
    check_metal,
    check_refine,
    check_refine_memory,
    load_scene,
    pick_backend,
    refine_cost,
    refine_map_size,
    refine_prediction,
    rerender,
    rerender_rmse,
)
from .relight import flash_consistency, relit_grid, relit_versions
from .tiles import check_tiled_memory, tile_count, tile_predict

__all__ = [
    "ALBEDO_ENCODINGS",
    "CaptureOptions",
    "MIN_TILEABLE_PHOTO",
    "NORMAL_ALIASES",
    "NORMAL_CONVENTIONS",
    "RELIT_FORMATS",
    "capture_one",
]

#: ``--normal-convention`` values: OpenGL (y up, the project's own) or DirectX (y down).
NORMAL_CONVENTIONS = ("opengl", "directx")
#: The smallest square (photo pixels) ``--tileable`` takes: the blend bands of
#: :func:`svbrdf_render.make_tileable` cover a quarter of the side at each border, and the part
#: they leave as it was must itself hold MIN_TILEABLE_SIDE (64) pixels of real detail.
MIN_TILEABLE_PHOTO = 128

#: Short names of the normal conventions.
NORMAL_ALIASES = {"gl": "opengl", "dx": "directx"}
#: ``--relit`` values: an animated GIF, a PNG grid of the frames, or no preview.
RELIT_FORMATS = ("gif", "png", "none")
#: How diffuse.png and specular.png store the albedos: linear (Des18) or sRGB (texture tools).
ALBEDO_ENCODINGS = ("linear", "srgb")


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


# -- one photo, end to end -----------------------------------------------------------------------


@dataclass(frozen=True)
class CaptureOptions:
    """How :func:`capture_one` reads a photo and what it writes.

    Attributes:
        linear: the file holds linear values (default: sRGB-encoded, as cameras save).
        crop: ``(x, y, size)`` in pixels of the oriented photo, or None for the centred square.
        tiles: predict at high resolution from overlapping tiles of the model's resolution.
        map_size: with ``tiles`` or ``refine``, the side of the maps, or ``"full"``: the
            square's own (default: the square's own with tiles; with refinement the square's
            own up to :data:`~svbrdf_models.capture.refining.DEFAULT_MAP_SIZE`, 1024 px).
        bits: 8 or 16, the maps' and input.png's PNG depth.
        normal_convention: ``"opengl"`` or ``"directx"`` (green channel flipped); ``"gl"`` and
            ``"dx"`` are read as those.
        relit: ``"gif"``, ``"png"`` or ``"none"``.
        albedo_encoding: how diffuse.png and specular.png store values: ``"srgb"`` (default,
            what colour inputs of texture tools such as Blender and Substance expect) or
            ``"linear"`` (Des18's convention, for research). basecolor.png is always sRGB.
        exr: also write the maps as OpenEXR (linear half floats).
        tileable: make the maps' opposite edges match (:func:`svbrdf_render.tiling.make_tileable`).
        refine: refinement steps after the network (0: the network's maps only).
        refine_seconds: with ``refine``, seconds for all of a photo; its refinement gets what the rest leave.
        scene: with ``refine``, the capture's scene, or its YAML file (read by
            :func:`~svbrdf_models.capture.refining.load_scene`; default: the flash found from the maps).
        backend: with ``refine``, the renderer's backend (``"auto"``, ``"eager"`` or ``"compiled"``).
        reference: a region of known albedo (:class:`svbrdf_models.capture.reference.Reference`) that
            pins the diffuse albedo's level, before any refinement.
        fov: the lens's field of view across the photo's longer side as displayed, in degrees,
            strictly between 1 and 179: where the camera stood follows from it and the square
            (:mod:`svbrdf_models.capture.geometry`; default: the photo's EXIF focal length).
        distance: the camera's height over the square's centre, in half-widths of the square
            (not with ``fov``). Without either, and without EXIF, the refinement's camera and flash
            stand at 2.2 half-widths over the photo's highlight.
        metal: ``"auto"`` (default) or ``"none"``: a dielectric, specular F0 0.04 grey everywhere
            and metallic 0, the refinement held to it (:data:`~svbrdf_models.capture.refining.METALS`).
    """

    linear: bool = False
    crop: tuple[int, int, int] | None = None
    tiles: bool = False
    map_size: int | str | None = None
    bits: int = 8
    normal_convention: str = "opengl"
    relit: str = "gif"
    albedo_encoding: str = "srgb"
    exr: bool = False
    tileable: bool = False
    refine: int = 0
    refine_seconds: float | None = None
    scene: Scene | str | Path | None = None
    backend: str = BACKEND
    reference: Reference | None = None
    fov: float | None = None
    distance: float | None = None
    metal: str = "auto"

    def __post_init__(self):
        self._check_together()
        convention = NORMAL_ALIASES.get(self.normal_convention, self.normal_convention)
        object.__setattr__(self, "normal_convention", convention)
        if self.albedo_encoding not in ALBEDO_ENCODINGS:
            raise DataError(
                f"albedo encoding must be one of {ALBEDO_ENCODINGS}, got {self.albedo_encoding!r}"
            )
        if self.normal_convention not in NORMAL_CONVENTIONS:
            raise DataError(
                f"normal convention must be one of {NORMAL_CONVENTIONS}, got {self.normal_convention!r}"
            )
        if self.relit not in RELIT_FORMATS:
            raise DataError(f"relit preview must be one of {RELIT_FORMATS}, got {self.relit!r}")
        if self.bits not in (8, 16):
            raise DataError(f"bits must be 8 or 16, got {self.bits}")
        if self.exr and importlib.util.find_spec("OpenEXR") is None:
            raise DataError("--exr needs the OpenEXR package: pip install 'svbrdf-render[exr]'")
        self._check_geometry()
        self._check_refine()
        check_metal(self.metal)
        if isinstance(self.scene, (str, Path)):  # a scene file, read once the options agree
            object.__setattr__(self, "scene", load_scene(self.scene))

    def _check_together(self) -> None:
        """The rules about which options go together, the one place they are written: the
        command line's flags reach them through this class, so its words are the flags'."""
        if self.map_size is not None and not (self.tiles or self.refine):
            raise DataError("--map-size goes with --tiles or --refine STEPS > 0")
        alone = [flag for flag, value in (("--refine-seconds", self.refine_seconds), ("--scene", self.scene))
                 if value is not None]  # fmt: skip
        if alone and not self.refine:
            verb = "goes" if len(alone) == 1 else "go"
            raise DataError(f"{' and '.join(alone)} {verb} with --refine STEPS > 0, not --refine 0")
        if self.reference is not None and self.scene is not None:
            raise DataError(
                "a reference (--reference) measures the flash and a scene (--scene) gives it: give one"
            )
        if self.scene is not None and (self.fov is not None or self.distance is not None):
            flag = "--fov" if self.fov is not None else "--distance"
            raise DataError(f"{flag} and --scene: the scene places the camera itself; give one of them")

    def _check_geometry(self) -> None:
        from .geometry import check_geometry_options

        fov, distance = check_geometry_options(self.fov, self.distance)
        object.__setattr__(self, "fov", fov)
        object.__setattr__(self, "distance", distance)

    def _check_refine(self) -> None:
        check_refine(self.refine, self.refine_seconds)
        if self.map_size is not None and self.map_size != FULL and not isinstance(self.map_size, int):
            raise DataError(f"map size must be a number of pixels or 'full', got {self.map_size!r}")
        if self.refine and isinstance(self.map_size, int) and self.map_size < MIN_REFINE_SIDE:
            raise DataError(
                f"map size (--map-size) {self.map_size} is smaller than {MIN_REFINE_SIDE} px: too few "
                "pixels to refine"
            )


@dataclass(frozen=True)
class _Judged:
    """What a capture shows and records: the maps to write, the figures and the entry's figures."""

    svbrdf: SVBRDF
    figure: Tensor
    frames: Tensor | None  # (V, n, 3, H, W): one set of relit frames per version
    versions: list[str]
    entry: dict


def capture_one(predictor, path, out_dir, options: CaptureOptions | None = None, *, progress=None) -> dict:
    """Capture one photo into the material folder ``out_dir``; its summary entry (status ``ok``).

    ``predictor`` has ``resolution`` and ``predict(photo)`` (a :class:`~svbrdf_models.TrainedModel`,
    or svbrdf-train's ``Predictor``; its ``predict_batch(photos)`` is used for tiles when it has
    one). Writes the maps (metal/rough and the project's own), material.json, material.gltf,
    material.mtlx, index.html, input.png (the square the maps are of, sRGB), rerender.png (photo
    | re-rendering | error heat map; with refinement the network's and the refined maps side by
    side) and relit.gif or relit.png: see :mod:`svbrdf_models.capture.material`. ``progress(step, total,
    loss)`` follows the refinement. A photo that cannot be used raises before any work; a folder
    that holds another material is refused by the writer, where the check and the move are one
    step under a lock (the commands check every photo's folder before the model loads, too); an
    interrupt or an error leaves ``out_dir`` as it was (staged, moved in whole).
    """
    from .material import MaterialContent, write_material

    options, began = options or CaptureOptions(), time.monotonic()  # the photo's --refine-seconds from here
    path, out_dir = Path(path), Path(out_dir)
    photo, notes = load_photo(path, linear=options.linear, crop=options.crop)
    geometry = capture_geometry(path, options.crop, fov=options.fov, distance=options.distance)
    side = photo.shape[-1]
    if options.tileable and side < MIN_TILEABLE_PHOTO:
        raise PhotoError(
            path,
            f"the square is {side} px; --tileable needs at least {MIN_TILEABLE_PHOTO} px of photo",
            "give a larger photo or --crop, or leave out --tileable",
        )
    seen = _without_card(photo, options, path)  # the network does not see a reference card
    square, svbrdf, tiles = _predict_square(predictor, seen, options, notes, path)
    svbrdf = as_dielectric(svbrdf) if options.metal == "none" else svbrdf  # no metal: F0 0.04 everywhere
    photo = square if seen is photo else square_photo(photo, square.shape[-1])
    geometry, found = place_flash(photo, _card_mask(options, path, photo), geometry, options)
    pinned = _pin_reference(svbrdf, photo, options, path, geometry)
    if pinned is not None:  # the card's pixels held at the card
        svbrdf = pinned.start(svbrdf)
    reference = None if pinned is None else pinned.record
    if options.refine:  # on the model's device, where the network ran
        device = getattr(predictor, "device", torch.device("cpu"))
        judged = _judge_refined(photo, svbrdf, options, progress, device, geometry, pinned, found[0], began)
    else:
        judged = _judge_network(photo, svbrdf, options)
    notes += record_flash(judged.entry["flash"], found, geometry, options)  # placed how; at the edge?
    svbrdf, relit, tileable = _finished(judged, options)
    entry = {
        "photo": str(path),
        "folder": str(out_dir),
        "status": "ok",
        "notes": notes,
        "square": side,
        "maps": int(svbrdf.size[0]),
        "tiles": tiles,
        **judged.entry,
        "tileable": tileable,
        "reference": reference,
    }
    record = _photo_record(predictor, path, options, entry, geometry)
    write_material(out_dir, svbrdf, MaterialContent(photo, judged.figure, relit, record), options)
    return entry


def _photo_record(predictor, path: Path, options, entry: dict, geometry) -> dict:
    """material.json's fields that a capture of one photo knows (its summary ``entry``, the
    camera's ``geometry``): the photo, the model, the refinement, the flash, the provenance."""
    from .material import model_record, photo_sha256, provenance
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


def _finished(judged: _Judged, options: CaptureOptions):
    """``(maps, relit preview, tileable record)``: the judged maps made tileable when asked,
    and the relit preview of the maps written (frames of a GIF, a PNG grid or None)."""
    svbrdf, frames, tileable = judged.svbrdf, judged.frames, None
    if options.tileable:
        svbrdf, tileable = _tileable(svbrdf)
        if options.relit != "none":  # the preview shows the maps written
            frames = torch.cat([frames[:-1], relit_versions([svbrdf])])
    if options.relit == "png":
        return svbrdf, relit_grid(frames, judged.versions if len(judged.versions) > 1 else None), tileable
    return svbrdf, frames[-1] if options.relit == "gif" else None, tileable


def _without_card(photo: Tensor, options: CaptureOptions, path: Path) -> Tensor:
    """The square ``photo`` as the network is shown it: with ``options.reference``'s region
    filled from the material around it (:func:`svbrdf_models.capture.reference.fill_card`)."""
    if options.reference is None:
        return photo
    from .reference import fill_card

    return fill_card(photo, _card_mask(options, path, photo))


def _card_mask(options: CaptureOptions, path: Path, photo: Tensor) -> Tensor | None:
    """``(1, 1, S, S)``: the reference card's pixels in the square ``photo``; None without one."""
    if options.reference is None:
        return None
    from .photos import square_box
    from .reference import reference_mask

    return reference_mask(options.reference, square_box(path, options.crop), photo.shape[-1], str(path))


def _pin_reference(svbrdf: SVBRDF, photo: Tensor, options: CaptureOptions, path: Path, geometry=None):
    """The flash measured on ``options.reference`` (a card of known albedo) in the square
    ``photo``, camera and flash where ``geometry`` puts them when it knows: a
    :class:`~svbrdf_models.capture.reference.PinnedFlash`; None without a reference."""
    if options.reference is None:
        return None
    from .photos import square_box
    from .reference import pin_flash

    known = geometry is not None and geometry.known
    return pin_flash(
        photo, svbrdf, options.reference, square_box(path, options.crop), str(path),
        position=torch.tensor(geometry.position, dtype=torch.float32) if known else None,
        focal=geometry.square_focal() if known else None,
    )  # fmt: skip


def _tileable(svbrdf: SVBRDF) -> tuple[SVBRDF, dict]:
    """The maps made tileable, and their seam errors before and after (median over channels)."""
    from svbrdf_render.tiling import make_tileable, seam_error

    def seams(m: SVBRDF) -> dict:
        return {name: round(float(seam_error(getattr(m, name))[0]), 3) for name in MAP_NAMES}

    before = seams(svbrdf)
    tiled = make_tileable(svbrdf)
    return tiled, {"seam_error_before": before, "seam_error_after": seams(tiled)}


def _judge_network(photo: Tensor, svbrdf: SVBRDF, options: CaptureOptions) -> _Judged:
    """The network's maps judged under the flash fitted to them."""
    fit = flash_consistency(svbrdf, photo)
    rmse = float(fit.rmse[0])
    figure = rerender_figure(photo, [fit.rendering[0]], [rmse], ["re-rendering"])
    frames = relit_versions([svbrdf]) if options.relit != "none" else None
    entry = {
        "rmse": _finite(rmse),
        "flash": {
            "position": [_finite(v) for v in fit.position[0].tolist()],
            "intensity": _finite(fit.intensity[0]),
        },
        "refine": None,
    }
    return _Judged(svbrdf, figure, frames, ["network"], entry)


def _judge_refined(photo: Tensor, network: SVBRDF, options: CaptureOptions, progress, device, geometry:
                   CaptureGeometry | None = None, pinned=None, point=None, began=None) -> _Judged:
    """The network's maps refined against ``photo`` on ``device`` (camera and flash where
    ``geometry`` puts them, when it knows); both judged under the refinement's scene. With
    ``pinned`` (a reference card), under the flash measured on it, the card's pixels held.
    ``point``: ``(1, 2)``, the photo's highlight (:func:`~svbrdf_models.capture.geometry.place_flash`)."""
    known = geometry is not None and geometry.known and options.scene is None and pinned is None
    result: Refinement = refine_prediction(
        photo[None],
        network.to(device),
        options.refine,
        seconds=options.refine_seconds, began=began,
        scene=options.scene if pinned is None else pinned.scene,
        callback=progress,
        backend=options.backend,
        camera=torch.tensor(geometry.position) if known else None,
        held=None if pinned is None else (pinned.mask, pinned.card),
        metal=options.metal, highlight=point,
    )
    size = tuple(photo.shape[-2:])
    renderings = [rerender(network, result.scene, size)[0], rerender(result.svbrdf, result.scene)[0]]
    rmse = rerender_rmse(torch.stack(renderings), photo).tolist()  # network's, refined
    versions = ["network", "refined"]
    figure = rerender_figure(photo, renderings, rmse, versions)
    frames = relit_versions([network, result.svbrdf]) if options.relit != "none" else None
    light = result.scene.point_lights[0]
    entry = {
        "rmse": _finite(rmse[1]),
        "flash": {
            "position": [_finite(v) for v in light.position.reshape(-1, 3)[0].tolist()],
            "intensity": _finite(light.intensity.reshape(-1)[0]),
        },
        "refine": {
            "budget": options.refine,
            "seconds_budget": options.refine_seconds,
            "steps": int(result.steps),
            "seconds": round(float(result.seconds), 3),
            "backend": pick_backend(options.backend, *size),
            "rmse_network": _finite(rmse[0]),
            "rmse_refined": _finite(rmse[1]),
        },
    }
    return _Judged(result.svbrdf, figure, frames, versions, entry)


def _predict_square(predictor, photo: Tensor, options: CaptureOptions, notes: list[str], path):
    """The photo's square brought to the size the maps are made at, the network's maps, and the
    tiles used (0: not tiled; 1: one tile). A square smaller than the model's resolution is
    noted (upsampled). With refinement the maps are made at ``map_size`` or the square's side."""
    res = int(predictor.resolution)
    side = photo.shape[-1]
    if not options.tiles:
        if side < res:
            soft = "the network sees it softened" if options.refine else "the maps will be soft"
            notes.append(f"the square ({side} px) is upsampled to the model's {res} px: {soft}")
        svbrdf = predictor.predict(photo)  # the predictor brings the square to its resolution
        size = refine_map_size(side, options.map_size) if options.refine else res
        _check_refine_size(size, options, path)
        if options.refine and options.map_size is None and size < side:
            notes.append(
                f"refined at {size} px, the default bound, of the {side} px square (--map-size full "
                f"refines all of it: about {refine_cost(side, options.refine)[1] / 2**30:.1f} GB)"
            )
        return square_photo(photo, size), svbrdf, 0
    size = side if options.map_size in (None, FULL) else options.map_size
    if size < res:
        notes.append(f"the square ({size} px) is smaller than a tile ({res} px): predicted as one tile")
        size = res
    check_tiled_memory(size, f"{path}: --tiles")
    photo = square_photo(photo, size)
    tiles = tile_count(size, res)
    batch_fn = getattr(predictor, "predict_batch", predictor.predict)
    svbrdf = tile_predict(batch_fn, photo, res) if tiles > 1 else predictor.predict(photo)
    return photo, svbrdf, tiles


def _check_refine_size(size: int, options: CaptureOptions, path) -> None:
    if options.refine and size < MIN_REFINE_SIDE:
        raise PhotoError(
            path,
            f"the maps would be {size} px, smaller than {MIN_REFINE_SIDE}: too few pixels to refine",
            "give a larger photo or --map-size, or --refine 0",
        )
    if options.refine:
        check_refine_memory(size, options.refine, str(path))
