"""Several handheld flash shots of one material in the printed frame, refined as one material
(``svbrdf-models predict a.jpg b.jpg c.jpg --shots -o maps/``).

One flash photo cannot separate a bright diffuse from a highlight, nor relief from albedo;
shots with the flash in different places can, when each one's camera and flash are known. The
printed frame (:mod:`~svbrdf_models.capture.frame`) tells them:

1. Each shot is read whole (EXIF-oriented, linear: :func:`~svbrdf_models.capture.photos.read_oriented`)
   and its frame found (:func:`~svbrdf_models.capture.framephoto.find_frame`). A shot without
   the frame is skipped with one line naming it; the others go on while one is left. Every
   shot must show the same frame (the markers of a frame of another size are refused).
2. The intrinsics: the focal length in pixels from ``--fov`` when given, else from the shot's
   EXIF (:func:`~svbrdf_models.capture.geometry.focal_pixels`); a shot with neither is refused
   (a pose needs the focal length). The principal point is the photo's centre.
3. Each shot's camera and flash (the lens-to-flash offset, ``--flash-offset``, default
   :data:`~svbrdf_models.capture.frame.FLASH_OFFSET_CM`) in half-widths of the window
   (:func:`~svbrdf_models.capture.framephoto.shot_pose`), and its window rectified into the
   material's square at the map size (default :data:`SHOTS_MAP_SIZE` at most the smallest
   window's side in pixels; ``--map-size``) with its reference strip sampled.
4. Exposure (:func:`exposures`): with ``--strip-albedo A`` each shot's flash intensity and
   colour are read off its strip through the renderer (:mod:`~svbrdf_models.capture.strip`),
   absolutely (``"strip"``); a strip more than half clipped or too dark is refused. Without it
   the most frontal shot's intensity is the median that makes the network's maps explain it
   (:func:`svbrdf_render.refinement.fit.axis_flash`, as a single photo's) and the others'
   follow from their strips' readings relative to its strip (``"relative"``: the paper's albedo
   cancels); a shot whose strip (or the frontal's) cannot be read gets the frontal's intensity
   and a gain the refinement learns (``"free"``), the frontal anchored at gain 1.
5. The network sees the most frontal shot (the smallest angle of its camera off the window's
   axis) once; its maps are the start and the prior of one
   :func:`svbrdf_render.refine_views` over every shot, each under its own camera and flash:
   a pixel clipped in a shot stays in its loss as a lower bound (:data:`CLIPPED_FLOOR`), the
   pixels around it are left out, and the normals are pulled towards
   :data:`SHOTS_PRIOR_RELIEF` of the network's relief.
6. Each shot's residual (the refinement's data term for it alone, the masked mean of
   ``|log(R + eps) - log(P + eps)|``), under the network's maps and under the refined ones: a
   shot whose residual under the network's maps is more than :data:`ODD_RATIO` times the
   median of the others' and above :data:`ODD_FLOOR`, and under the refined maps more than
   :data:`ODD_REFINED` times theirs, is not explained by the material the others show: "shots
   of different materials?", exit 2, nothing written.

:func:`prepare_shots` does steps 1-3 and reads the strips, before the model loads;
:func:`svbrdf_models.capture.shotcapture.capture_shots` the rest. The material folder
``OUT/<first shot's stem>/`` is written as a calibrated set's
(:mod:`~svbrdf_models.capture.calibrated`): material.json's ``shots`` holds each shot's file,
camera, light, flash offset, focal length and its source, intensity, colour, exposure source,
gain, RMSEs and residual, and whether it was used; the viewer (index.html) puts its light where
each shot's flash was (keys 1-9). One shot with the frame is a calibrated single capture.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import MIN_REFINE_SIDE, SVBRDF, Camera, PointLight, RefineSettings, Scene

from ..errors import DataError
from .frame import FLASH_OFFSET_CM
from .framephoto import FrameDetection
from .strip import NOMINAL_ALBEDO, StripReading, check_strip, read_strip

__all__ = ["CLIPPED_FLOOR", "ODD_FLOOR", "ODD_RATIO", "ODD_REFINED", "SHOTS_COARSE", "SHOTS_MAP_SIZE",
           "SHOTS_PRIOR_RELIEF", "Exposure", "Shot", "ShotSet", "check_options", "exposures",
           "fitted_masks", "prepare_shots", "prior_relief", "refine_settings", "shot_scene"]  # fmt: skip

#: The side the shots' maps are made at unless --map-size says otherwise (at most the smallest
#: window's side in pixels): each refinement step renders every shot.
SHOTS_MAP_SIZE = 256
#: A rectified pixel with a channel at or above this is clipped: its true value is at least
#: this, not this.
CLIPPED = 0.98
#: Whether a clipped pixel stays in its shot's loss as a lower bound (the renderings are
#: clipped to [0, 1] as the camera's are, so a rendering at least as bright costs nothing and a
#: darker one is pulled up) rather than left out: a glossy material's highlight is a few
#: clipped pixels, the only place a shot shows how sharp it is. The pixels beside a clipped
#: one (rectified from both) stay out.
CLIPPED_FLOOR = True
#: A shot is of another material when its residual (the refinement's data term for it alone:
#: the masked mean of |log(rendering + eps) - log(photo + eps)|) under the network's maps of
#: the frontal shot is more than ODD_RATIO times the median of the other shots' and above
#: ODD_FLOOR, and under the refined maps more than ODD_REFINED times theirs. The refinement of
#: several shots is free enough (:func:`refine_settings`) to explain much of another
#: material's photo, so its residual alone no longer tells (on the synthetic shots of
#: tests/models/test_models_shots.py, 64 px: a leather's two shots and a tiles' one left 0.09,
#: 0.05, 0.19 after 30 steps, 0.06, 0.02, 0.12 after 100), while the network's maps of the
#: leather explain the tiles' shot five times worse than the leather's (1.03 against 0.20-0.22).
#: The refined check keeps a shot the network's start happens to miss from being refused: on
#: the 18 captures of 3 and 5 shots of docs/measured-shots.md no shot's refined residual was
#: more than 1.84 times the others' median (at most 0.041).
ODD_RATIO = 3.0
ODD_FLOOR = 0.25
ODD_REFINED = 2.0
#: Where a shot's exposure came from (see the module).
EXPOSURES = ("strip", "relative", "free")
#: K shots (two or more) are refined with each map's pull towards the network's start at 1/K of
#: a single photo's (``RefineSettings.prior``), and roughness and specular free per pixel
#: (``coarse`` :data:`SHOTS_COARSE`) instead of on an 8 x 8 grid: one photo needs the prior to
#: separate what it cannot, each shot under a flash elsewhere separates more of it, and the
#: single photo's weights held several shots to the network's start (a metal's diffuse, its
#: flakes' specular, near-flat normals). Measured on unseen-dev's 9 materials at 512 px
#: (docs/measured-shots.md, "Several shots, a lighter prior").
SHOTS_COARSE = 0
#: K shots (two or more) pull the normals towards this share of the relief of the network's
#: normals of the frontal shot (where they start): 1 the network's normals, 0 a flat surface
#: (:func:`svbrdf_models.capture.multiview.flatter`). One photo cannot tell relief from albedo
#: and needs the network's guess; several shots under flashes elsewhere show the relief that is
#: there, and the network's guess of relief on a flat material (a polished stone, a metal) is
#: what no shot contradicts strongly enough. unseen-dev 5 shots: normals -5% [-8, -2], every
#: map better beyond noise, des18-dev none worse; flatter shares did better on both, but lost
#: the relief of tests/models/test_models_shots.py's leather (docs/measured-shots.md, "The
#: normals pulled towards flat").
SHOTS_PRIOR_RELIEF = 0.5


@dataclass(frozen=True, eq=False)
class Shot:
    """One shot of the set: where it was taken from and what it shows (half-widths of the window).

    ``window``: ``(3, S, S)`` linear, the top row at y = +1; ``strip``/``strip_xy``: the
    reference strip's samples and where they lie; ``mask``: ``(1, S, S)`` the pixels used."""

    path: Path
    detection: FrameDetection
    camera: Tensor
    flash: Tensor
    focal_px: float
    focal_source: str
    window_px: float
    markers: int
    marker_rms_px: float
    window: Tensor | None = None
    strip: Tensor | None = None
    strip_xy: Tensor | None = None
    mask: Tensor | None = None

    @property
    def angle(self) -> float:
        """The camera's angle off the window's axis, degrees."""
        return math.degrees(math.atan2(float(self.camera[:2].norm()), float(self.camera[2])))


@dataclass
class ShotSet:
    """The shots found (:func:`prepare_shots`), the frame they show and the map size."""

    shots: list[Shot]
    skipped: list[tuple[Path, str]]
    window_cm: float
    size: int
    folder: Path
    flash_offset_cm: tuple[float, float]
    strip_albedo: float | None
    readings: list[StripReading] = field(default_factory=list)

    @property
    def frontal(self) -> int:
        """The shot whose camera is closest to the window's axis."""
        return min(range(len(self.shots)), key=lambda i: self.shots[i].angle)

    def sha256(self) -> str:
        """The set's identity: a SHA-256 over the shots' files (names and bytes), in order."""
        return _sha256([s.path for s in self.shots])


def _sha256(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def check_options(options) -> None:
    """Refuse the options shots do not take: their square is the frame's window and each
    camera is placed by the markers."""
    flags = {"--tiles": options.tiles, "--crop": options.crop, "--scene": options.scene,
             "--reference": options.reference, "--tileable": options.tileable,
             "--distance": options.distance}  # fmt: skip
    given = [flag for flag, value in flags.items() if value not in (None, False)]
    if given:
        raise DataError(f"--shots with {given[0]}: the shots' square is the printed frame's window and their "
                        "cameras are placed by its markers; leave it out")  # fmt: skip


class _NoFocal(DataError):
    """A shot without a focal length: no shot can be posed, the capture stops."""


def _focal(path: Path, size: tuple[int, int], fov: float | None) -> tuple[float, str]:
    """The focal length in pixels of the photo as displayed (``size`` = (H, W)), and its source."""
    from .geometry import exif_focal, focal_pixels

    if fov is not None:
        return (max(size) / 2) / math.tan(math.radians(fov) / 2), "fov"
    found = focal_pixels(exif_focal(path))
    if found is None:
        raise _NoFocal(f"{path}: no focal length in its EXIF; give --fov DEG, the lens's field of view "
                       "across the photo's longer side (a shot's pose needs the focal length)")  # fmt: skip
    return found


def _find(path: Path, options, flash_offset_cm) -> tuple[Shot, float]:
    """A shot's frame found and its camera and flash placed; ``(shot, window_cm)``."""
    from .framephoto import find_frame, shot_pose
    from .photos import read_oriented

    image, _ = read_oriented(path, linear=options.linear)
    focal, source = _focal(path, tuple(image.shape[-2:]), options.fov)
    found = find_frame(image, name=str(path), linear=True)
    pose = shot_pose(found, focal, flash_offset_cm=flash_offset_cm)
    sides = torch.from_numpy(found.window - found.window[[1, 2, 3, 0]]).norm(dim=1)
    shot = Shot(path, found, pose.camera, pose.flash, float(focal), source, float(sides.mean()),
                len(found.ids), float(found.rms_px))  # fmt: skip
    return shot, found.layout.window_cm


def _found_shots(paths: list[Path], options, flash_offset_cm, warn):
    """Every shot whose frame is found, with the frame's window (cm) of each, and the skipped."""
    found, skipped = [], []
    for path in paths:
        try:
            found.append((*_find(path, options, flash_offset_cm), path))
        except _NoFocal:
            raise
        except DataError as e:  # unreadable, no frame, no pose: this shot alone
            skipped.append((path, str(e)))
    if not found:
        names = ", ".join(p.name for p in paths)
        raise DataError(f"the frame was found in none of the {len(paths)} shot(s) ({names}): {skipped[0][1]}")
    for path, why in skipped:
        warn(f"note: {why if str(path) in why else f'{path}: {why}'}; skipped, the other shots go on")
    return found, skipped


def _same_frame(found) -> float:
    """The frame's window (cm) the shots show; shots of two frames are refused."""
    sizes = [w for _, w, _ in found]
    common = max(sizes, key=lambda w: (sizes.count(w), -sizes.index(w)))
    odd = [(p, w) for _, w, p in found if w != common]
    if odd:
        first = next(p for _, w, p in found if w == common)
        path, w = odd[0]
        raise DataError(f"markers of another frame in {path}: the {w:g} cm frame, where {first} shows the "
                        f"{common:g} cm frame; photograph the one frame in every shot")  # fmt: skip
    return common


def _map_size(shots: list[Shot], options) -> int:
    from .refining import FULL

    smallest = max(1, int(min(s.window_px for s in shots)))
    if options.map_size == FULL:
        return smallest
    return int(options.map_size) if options.map_size is not None else min(SHOTS_MAP_SIZE, smallest)


def _rectified(shot: Shot, size: int, options) -> Shot:
    """``shot`` with its window (and its mask of unclipped pixels) and its strip at ``size``."""
    import dataclasses

    import torch.nn.functional as F

    from .framephoto import rectify
    from .photos import read_oriented

    image, _ = read_oriented(shot.path, linear=options.linear)  # read again: one whole photo held at a time
    out = rectify(image, shot.detection, size)
    clipped = (out.window.amax(0, keepdim=True) >= CLIPPED).float()
    mask = 1 - F.max_pool2d(clipped[None], 3, stride=1, padding=1)[0]
    return dataclasses.replace(shot, window=out.window.clamp(0, 1), strip=out.strip, strip_xy=out.strip_xy,
                               mask=mask)  # fmt: skip


def prepare_shots(paths, out: Path, options, *, strip_albedo: float | None = None,
                  flash_offset_cm=FLASH_OFFSET_CM, warn=print) -> ShotSet:  # fmt: skip
    """Steps 1-3 of the module and the strips read, before the model loads: every refusal is a
    one-line :class:`DataError`; ``warn(line)`` says which shots were skipped. The material
    folder is ``out/<first shot's stem>``, refused when it holds another material."""
    from .batch import folder_name
    from .material import check_material_folder

    check_options(options)
    paths = [Path(p) for p in paths]
    offset = tuple(float(v) for v in flash_offset_cm)
    found, skipped = _found_shots(paths, options, offset, warn)
    window_cm = _same_frame(found)
    shots = [s for s, _, _ in found]
    size = _map_size(shots, options)
    if options.refine and size < MIN_REFINE_SIDE:
        least = MIN_REFINE_SIDE
        raise DataError(f"--shots: maps of {size} px are too few pixels to refine (at least {least}); give a "
                        "larger --map-size or photograph the frame larger")  # fmt: skip
    if options.refine:
        from .refining import check_refine_memory

        remedy = "give a smaller --map-size, fewer shots or --refine 0"
        check_refine_memory(size, options.refine, "--shots", count=len(shots), remedy=remedy)
    folder = Path(out) / folder_name(paths[0], set())
    check_material_folder(folder, paths[0], sha256=_sha256([s.path for s in shots]))
    shots = [_rectified(s, size, options) for s in shots]
    albedo = strip_albedo or NOMINAL_ALBEDO
    readings = [read_strip(s.strip, s.strip_xy, s.camera, s.flash, albedo) for s in shots]
    if strip_albedo is not None:
        for shot, reading in zip(shots, readings, strict=True):
            check_strip(reading, str(shot.path))
    return ShotSet(shots, skipped, window_cm, size, folder, offset, strip_albedo, readings)


@dataclass(frozen=True)
class Exposure:
    """Each shot's flash: ``intensity`` ``(K,)``, ``color`` ``(K, 3)``, ``source`` (one of
    :data:`EXPOSURES`) and the refinement's gains mode and anchored shots."""

    intensity: Tensor
    color: Tensor
    source: list[str]

    @property
    def gains(self) -> str:
        return "free" if "free" in self.source else "fixed"

    @property
    def anchor(self) -> list[int]:
        return [i for i, s in enumerate(self.source) if s != "free"]


def exposures(shots: ShotSet, start: SVBRDF) -> Exposure:
    """Each shot's flash (step 4 of the module); ``start``: the network's maps at the map size,
    which set the frontal shot's intensity when no strip albedo is stated."""
    from svbrdf_render.refinement.fit import axis_flash

    k, f = len(shots.shots), shots.frontal
    readings = shots.readings
    if shots.strip_albedo is not None:
        intensity = torch.tensor([r.intensity for r in readings])
        return Exposure(intensity, torch.stack([r.color for r in readings]), ["strip"] * k)
    front = shots.shots[f]
    scene = axis_flash(start, front.window[None], position=front.flash)
    level = float(scene.point_lights[0].intensity.reshape(-1)[0])
    intensity, source = torch.full((k,), level), ["free"] * k
    for i, reading in enumerate(readings):
        if i == f or (reading.readable and readings[f].readable):
            intensity[i] = level * reading.intensity / readings[f].intensity if i != f else level
            source[i] = "relative"
    return Exposure(intensity, torch.ones(k, 3), source)


def fitted_masks(windows: Tensor, masks: Tensor) -> Tensor:
    """``(K, 1, S, S)`` the pixels each shot's refinement compares: ``masks`` (neither clipped
    nor beside a clipped pixel) and, with :data:`CLIPPED_FLOOR`, the clipped pixels as lower
    bounds."""
    if not CLIPPED_FLOOR:
        return masks
    clipped = (windows.amax(1, keepdim=True) >= CLIPPED).to(masks.dtype)
    return torch.maximum(masks, clipped)


def refine_settings(shots: int) -> RefineSettings | None:
    """How ``shots`` shots are refined together: a single photo's settings for one; for more,
    the prior at ``1 / shots`` of a single photo's and roughness and specular per pixel
    (:data:`SHOTS_COARSE`)."""
    if shots < 2:
        return None
    single = RefineSettings()
    prior = {name: weight / shots for name, weight in single.prior.items()}
    return dataclasses.replace(single, prior=prior, coarse=SHOTS_COARSE)


def prior_relief(shots: int) -> float:
    """The share of the network's relief ``shots`` shots pull the normals towards:
    :data:`SHOTS_PRIOR_RELIEF` for two or more, 1 (the network's normals) for one."""
    return float(SHOTS_PRIOR_RELIEF) if shots >= 2 else 1.0


def shot_scene(shot: Shot, intensity: float, color: Tensor) -> Scene:
    """A shot's scene: its camera, its flash of ``intensity`` and ``color``, Des18's effects."""
    return Scene(Camera(shot.camera), (PointLight(shot.flash, float(intensity), color),))
