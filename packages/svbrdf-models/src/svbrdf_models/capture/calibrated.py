"""Calibrated sets: several rectified photos of one material with their cameras and lights known,
as MaterialGAN (Guo et al. 2020, "MaterialGAN: Reflectance Capture using a Generative SVBRDF
Model") publishes its real captures, refined as one material (``predict --calibrated DIR``)::

    DIR/00.png, 01.png, ...   the photos, rectified: each covers the patch, image top = +y
    DIR/camera_pos.txt        one camera position per photo, "x,y,z" a line, in cm
    DIR/light_pos.txt         one light position per photo (absent: the camera's, a flash)
    DIR/image_size.txt        the side of the patch the photos cover, in cm
    DIR/light_power.txt       "r,g,b" (or one number): the light's power, one line for every
                              photo or one line per photo

What their code says (the repository tflsguoyu/materialgan; read there, not copied):

- Units and origin: ``src/render.py`` (class ``Microfacet``) places pixel ``i`` of ``res`` at
  ``((i + 0.5) / res - 0.5) * size`` with ``size`` the number of ``image_size.txt``: the patch is
  centred on the origin at ``z = 0`` and every length is in cm (``tools/generate_inputs.py``
  writes ``image_size.txt`` as the crop's side in cm, from the printed markers' layout, and
  the camera positions from OpenCV's calibration in the markers' frame, also cm).
- Axes and orientation: the same line stacks ``(x, -y, 0)`` with ``y`` the row, so the image's
  top row is ``+y``, x to the right, z up out of the surface toward the cameras (``z`` about
  17 cm in their ``real_cards-blue``); ``generate_inputs.py`` flips the rows when it rectifies
  (``res - y``). The project's convention is the same (row 0 is ``y = +1``).
- Light: ``copy_to_folder`` in ``generate_inputs.py`` writes ``light_pos.txt`` as a copy of
  ``camera_pos.txt`` (a phone's flash at its lens), hence the fallback here; ``light_power.txt``
  is one line ``1500,1500,1500`` for the whole set. ``Microfacet.eval`` renders
  ``f * max(n.l, 0) / d^2 * power`` with ``d`` in cm: an intensity per colour and a ``1/d^2``
  falloff, then clamps to [0, 1].
- Encoding: ``src/optim.py`` loads ``%02d.png`` as ``value / 255`` and ``src/loss.py`` compares
  them with ``rendering.clamp(eps, 1) ** (1 / 2.2)``: the photos hold ``linear ** (1 / 2.2)``,
  a pure 2.2 gamma (not the sRGB curve). They are read here as ``png ** 2.2`` (``--linear``:
  as stored).
- BRDF: ``Microfacet`` is Des18's, the project's default: GGX ``D`` with ``alpha = rough^2``,
  Smith-Schlick ``G`` with ``k = alpha / 2``, the spherical-Gaussian Schlick Fresnel
  (``Fresnel_S``, F0 = specular), diffuse ``albedo (1 - specular) / pi`` and
  ``D F G / (4 n.v n.l)``. Only the floor differs: theirs clamps ``rough`` at 1e-6, the
  project's ``alpha = 0.001 + 0.999 r^2``. Their normal's y is the image's up, as here.

Conversion to the project's units (the patch ``[-1, 1]^2``, lengths in half-widths): with
``h = side / 2`` cm, a position ``p`` cm is ``p / h`` half-widths, and since
``power / d_cm^2 = power / (h^2 d^2)`` with ``d`` in half-widths, the intensity is
``power / h^2`` (divided by the squared half side); the colour is ``power / max(power)``.

The capture (:func:`capture_calibrated`): the network sees the most frontal view used (its
camera closest to the axis); its maps (without their 2-pixel pattern) are the start and the
prior of one :func:`svbrdf_render.refine_views` over every view used, each under its own
camera and light, gains fixed (the light's power is known: a free gain would trade with the
albedo). With ``holdout`` the views not used are re-rendered under their own camera and light
and compared with their photos: the relighting RMSE, the field's test on real photos, which
copying a photo into the diffuse map cannot win.
"""

from __future__ import annotations

import hashlib
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from svbrdf_render import MIN_REFINE_SIDE, Camera, PointLight, Scene, read_image

from ..errors import DataError
from .photos import square_photo
from .multiview import Judged, finite, judge, refine_network, relit_preview, views_figure
from .refining import as_dielectric, check_refine_memory, pick_backend

__all__ = ["CALIBRATED_GAMMA", "CALIBRATED_MAP_SIZE", "CalibratedSet", "capture_calibrated", "check_views",
           "check_options", "read_calibrated"]  # fmt: skip

#: The pure power the set's PNGs are encoded with (``src/loss.py`` of MaterialGAN).
CALIBRATED_GAMMA = 2.2
#: The side the maps of a calibrated set are refined at unless --map-size says otherwise:
#: MaterialGAN's own resolution; each step renders every view used, K times one photo's work.
CALIBRATED_MAP_SIZE = 256
_PHOTO = re.compile(r"^(\d{2,})\.png$")
_TEXTS = ("camera_pos.txt", "image_size.txt", "light_power.txt")


@dataclass(frozen=True)
class CalibratedSet:
    """A calibrated set as published (lengths in cm): read by :func:`read_calibrated`.

    Attributes:
        folder: the set's folder.
        files: the photos ``00.png, 01.png, ...``.
        side_cm: the patch's side.
        camera_cm, light_cm: ``(N, 3)`` positions over the patch's centre.
        power: ``(N, 3)`` the light's power per colour, in their units (cm^2 for the falloff).
        light_file: where the light positions came from (``camera_pos.txt``: a flash).
    """

    folder: Path
    files: tuple[Path, ...]
    side_cm: float
    camera_cm: Tensor
    light_cm: Tensor
    power: Tensor
    light_file: str

    @property
    def half_cm(self) -> float:
        return self.side_cm / 2

    @property
    def camera(self) -> Tensor:
        """``(N, 3)`` camera positions in half-widths of the patch."""
        return self.camera_cm / self.half_cm

    @property
    def light(self) -> Tensor:
        """``(N, 3)`` light positions in half-widths of the patch."""
        return self.light_cm / self.half_cm

    @property
    def intensity(self) -> Tensor:
        """``(N,)`` the lights' intensities for positions in half-widths: ``max power / h^2``."""
        return self.power.amax(1) / self.half_cm**2

    def scene(self, i: int) -> Scene:
        """View ``i``: its camera, its light (colour ``power / max power``), Des18's effects."""
        peak = self.power[i].amax()
        colour = self.power[i] / peak if float(peak) > 0 else torch.ones(3)
        light = PointLight(self.light[i], float(self.intensity[i]), colour)
        return Scene(Camera(self.camera[i]), (light,))

    def frontal(self, views: list[int]) -> int:
        """The view of ``views`` whose camera is closest to the axis (smallest angle off it)."""
        cam = self.camera_cm[views]
        angle = torch.atan2(cam[:, :2].norm(dim=1), cam[:, 2])
        return views[int(angle.argmin())]

    def sha256(self) -> str:
        """The set's identity: a SHA-256 over its photos' and text files' bytes."""
        digest = hashlib.sha256()
        for path in [*self.files, *(self.folder / n for n in (*_TEXTS, self.light_file))]:
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
        return digest.hexdigest()


def _photo_files(folder: Path) -> tuple[Path, ...]:
    found = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := _PHOTO.match(p.name)))
    if not found:
        raise DataError(f"--calibrated {folder}: no photos 00.png, 01.png, ...; not a calibrated set")
    for i, (number, _) in enumerate(found):
        if number != i:
            raise DataError(f"--calibrated {folder}: no {i:02d}.png but {found[-1][1].name}; the photos "
                            "are numbered from 00 without a gap")  # fmt: skip
    return tuple(p for _, p in found)


def _rows(path: Path, widths: tuple[int, ...], what: str) -> list[list[float]]:
    """The numbers of each non-blank line of ``path`` (commas or spaces between them), each line
    ``widths`` long; a missing file, a word or a non-finite number is a one-line DataError."""
    if not path.is_file():
        raise DataError(f"--calibrated {path.parent}: no {path.name} ({what}); not a calibrated set")
    rows = []
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            values = [float(v) for v in re.split(r"[,\s]+", line.strip())]
        except ValueError:
            values = []
        if len(values) not in widths or not all(math.isfinite(v) for v in values):
            want = " or ".join(str(w) for w in widths)
            shown = line.strip()[:60]
            raise DataError(f"--calibrated {path}: line {n} {shown!r} is not {want} number(s) ({what})")
        rows.append(values)
    if not rows:
        raise DataError(f"--calibrated {path}: empty; expected {what}")
    return rows


def _positions(path: Path, count: int, what: str) -> Tensor:
    rows = _rows(path, (3,), what)
    if len(rows) != count:
        raise DataError(f"--calibrated {path.parent}: {count} photos but {len(rows)} {what} ({path.name})")
    t = torch.tensor(rows, dtype=torch.float32)
    if bool((t[:, 2] <= 0).any()):
        line = int((t[:, 2] <= 0).nonzero()[0]) + 1
        raise DataError(f"--calibrated {path}: position {line} is not above the patch (z <= 0)")
    return t


def read_calibrated(folder, *, linear: bool = False) -> tuple[CalibratedSet, Tensor]:
    """The set in ``folder`` and its photos ``(N, 3, S, S)``, linear (decoded from the 2.2 gamma
    unless ``linear``). Every refusal is one line (:class:`DataError`), before any work."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"--calibrated {folder}: no such folder")
    files = _photo_files(folder)
    n = len(files)
    camera = _positions(folder / "camera_pos.txt", n, "camera positions")
    light_file = "light_pos.txt" if (folder / "light_pos.txt").exists() else "camera_pos.txt"
    light = _positions(folder / light_file, n, "light positions")
    side = _rows(folder / "image_size.txt", (1,), "the patch's side in cm")
    if len(side) != 1 or not side[0][0] > 0:
        raise DataError(f"--calibrated {folder / 'image_size.txt'}: expected one side in cm > 0")
    power = _rows(folder / "light_power.txt", (1, 3), "the light's power")
    if len(power) not in (1, n):
        raise DataError(f"--calibrated {folder}: {n} photos but {len(power)} light powers (light_power.txt: "
                        "one line for all, or one per photo)")  # fmt: skip
    power_t = torch.tensor([p * 3 if len(p) == 1 else p for p in power], dtype=torch.float32).expand(n, 3)
    if bool((power_t < 0).any()):
        raise DataError(f"--calibrated {folder / 'light_power.txt'}: a negative power")
    cal = CalibratedSet(folder, files, float(side[0][0]), camera, light, power_t.contiguous(), light_file)
    return cal, _read_photos(files, linear)


def _read_photos(files: tuple[Path, ...], linear: bool) -> Tensor:
    from svbrdf_render import SVBRDFError

    photos = []
    for path in files:
        try:
            image = read_image(path)
        except (SVBRDFError, OSError) as e:
            raise DataError(f"--calibrated {path}: cannot be read as a photo ({e})") from None
        if image.shape[-1] != image.shape[-2] or image.shape[-2:] != (photos or [image])[0].shape[-2:]:
            size = f"{image.shape[-1]}x{image.shape[-2]}"
            raise DataError(f"--calibrated {path}: {size}; a set's photos are rectified squares of one size")
        photos.append(image if linear else image.clamp_min(0) ** CALIBRATED_GAMMA)
    return torch.stack(photos)


def check_views(use: list[int] | None, count: int, holdout: bool) -> list[int]:
    """The views refined against (``use``, default all of them), checked against ``count``
    photos: an index out of range or repeated, or every view used with ``holdout``, is refused."""
    views = list(range(count)) if use is None else list(use)
    bad = [i for i in views if not 0 <= i < count]
    if bad:
        raise DataError(f"--use {bad[0]}: the set has views 0 to {count - 1}")
    twice = sorted({i for i in views if views.count(i) > 1})
    if twice:
        raise DataError(f"--use names view {twice[0]} twice")
    if holdout and len(views) == count:
        raise DataError(f"--holdout with every one of the {count} views used: no view is left to judge; "
                        "give --use with fewer views")  # fmt: skip
    return views


def _map_size(side: int, options) -> int:
    """The side the set's maps are made at: --map-size (``full``: the photos' own), else
    :data:`CALIBRATED_MAP_SIZE` at most."""
    from .refining import FULL

    if options.map_size == FULL:
        return side
    return int(options.map_size) if options.map_size is not None else min(side, CALIBRATED_MAP_SIZE)


def check_options(options) -> None:
    """Refuse the options a calibrated set does not take (its photos are rectified squares and
    its cameras and lights are given)."""
    flags = {"--tiles": options.tiles, "--crop": options.crop, "--scene": options.scene,
             "--reference": options.reference, "--tileable": options.tileable,
             "--fov": getattr(options, "fov", None),
             "--distance": getattr(options, "distance", None)}  # fmt: skip
    given = [flag for flag, value in flags.items() if value not in (None, False)]
    if given:
        raise DataError(f"--calibrated with {given[0]}: a calibrated set's photos are rectified squares "
                        "whose cameras and lights are given; leave it out")  # fmt: skip


def _shots(cal: CalibratedSet, used: list[int], judged: Judged, gains: Tensor, frontal: int) -> list[dict]:
    """material.json's ``shots``: each view's file, camera and light (half-widths), intensity,
    gain, RMSEs, and whether it was used or held out."""
    out = []
    for i, path in enumerate(cal.files):
        gain = float(gains[used.index(i)]) if i in used else None
        out.append({
            "file": path.name, "camera": [finite(v) for v in cal.camera[i].tolist()],
            "light": [finite(v) for v in cal.light[i].tolist()], "intensity": finite(cal.intensity[i]),
            "color": [finite(v) for v in (cal.power[i] / cal.power[i].amax().clamp_min(1e-12)).tolist()],
            "gain": gain, "used": i in used, "held_out": i not in used, "network_view": i == frontal,
            "rmse_network": finite(judged.rmse_network[i]), "rmse": finite(judged.rmse[i]),
        })  # fmt: skip
    return out


def _holdout(cal: CalibratedSet, used: list[int], judged: Judged) -> dict | None:
    held = [i for i in range(len(cal.files)) if i not in used]
    if not held:
        return None

    def mean(values: list[float]) -> float | None:
        return finite(sum(values[i] for i in held) / len(held))

    return {
        "views": [cal.files[i].name for i in held],
        "rmse": {cal.files[i].name: finite(judged.rmse[i]) for i in held},
        "rmse_network": {cal.files[i].name: finite(judged.rmse_network[i]) for i in held},
        "mean": mean(judged.rmse),
        "mean_network": mean(judged.rmse_network),
        "measure": "RMSE of the clipped re-rendering under the view's own camera and light against "
        "its photo, both linear",
    }


def _figure(cal: CalibratedSet, photos: Tensor, judged: Judged, used: list[int]) -> Tensor:
    """rerender.png: a row per view: photo | network's | refined re-rendering | refined error."""
    return views_figure(photos, judged, [f"{p.name} {'used' if i in used else 'held out'}"
                                         for i, p in enumerate(cal.files)])  # fmt: skip


def capture_calibrated(predictor, folder, out_dir, options, *, use: list[int] | None = None,
                       holdout: bool = False, progress=None) -> dict:  # fmt: skip
    """Capture the calibrated set in ``folder`` (or the pair :func:`read_calibrated` gave) into
    the material folder ``out_dir`` (see the module); material.json's content. ``options`` is a
    :class:`~svbrdf_models.capture.one.CaptureOptions` (the maps' files, the refinement's
    budget); ``use`` the views refined against (default all); ``holdout`` judges the others. A
    folder that holds another material is refused by the writer (``predict --calibrated``
    refuses it before the model loads)."""
    from .material import MaterialContent, write_material

    began = time.monotonic()  # --refine-seconds covers the whole capture from here
    check_options(options)
    cal, photos = folder if isinstance(folder, tuple) else read_calibrated(folder, linear=options.linear)
    used = check_views(use, len(cal.files), holdout)
    size = _map_size(photos.shape[-1], options)
    if options.refine and size < MIN_REFINE_SIDE:
        raise DataError(f"--calibrated {cal.folder}: maps of {size} px are too few pixels to refine "
                        f"(at least {MIN_REFINE_SIDE})")  # fmt: skip
    if options.refine:
        remedy = "give a smaller --map-size, fewer views (--use) or --refine 0"
        where = f"--calibrated {cal.folder}"
        check_refine_memory(size, options.refine, where, count=len(used), remedy=remedy)
    frontal = cal.frontal(used)
    network = predictor.predict(photos[frontal]).detach().to("cpu", torch.float32)
    network = as_dielectric(network) if options.metal == "none" else network  # no metal: F0 0.04
    small = torch.stack([square_photo(p, size) for p in photos])
    device = getattr(predictor, "device", torch.device("cpu"))
    result = refine_network(network, small[used], [cal.scene(i) for i in used], options, progress, device,
                            began=began)
    refined = result.svbrdf.to("cpu")
    judged = judge(small, [cal.scene(i) for i in range(len(cal.files))], network, refined)
    record = _record(predictor, cal, cal.sha256(), options, size, used, frontal, judged, result)
    figure, relit = _figure(cal, small, judged, used), relit_preview(network, refined, options)
    write_material(out_dir, refined, MaterialContent(small[frontal], figure, relit, record), options)
    return record


def _record(predictor, cal, sha, options, size, used, frontal, judged: Judged, result) -> dict:
    """material.json's fields that the calibrated capture knows."""
    from .material import model_record, provenance

    mean = finite(sum(judged.rmse[i] for i in used) / len(used))
    return {
        "name": cal.folder.name,
        "photo": {"file": cal.folder.name, "sha256": sha, "square": int(size), "crop": None,
                  "encoding": "linear" if options.linear else f"gamma {CALIBRATED_GAMMA:g}",
                  "network_view": cal.files[frontal].name},  # fmt: skip
        "model": model_record(predictor),
        "maps_size": int(size),
        "tiles": 0,
        "rerender_rmse": mean,
        "flash": {"position": [finite(v) for v in cal.light[frontal].tolist()],
                  "intensity": finite(cal.intensity[frontal])},  # fmt: skip
        "refine": {"budget": options.refine, "seconds_budget": options.refine_seconds,
                   "steps": int(result.steps), "seconds": round(float(result.seconds), 3),
                   "views": len(used), "gains": "fixed",
                   "backend": pick_backend(options.backend, size, size),
                   "rmse_network": finite(sum(judged.rmse_network[i] for i in used) / len(used)),
                   "rmse_refined": mean},  # fmt: skip
        "calibrated": {
            "folder": str(cal.folder), "convention": "MaterialGAN (Guo et al. 2020): cm, origin at the "
            "patch's centre, +z toward the cameras, image top +y", "side_cm": cal.side_cm,
            "half_width_cm": cal.half_cm, "light_positions": cal.light_file,
            "units": "positions in half-widths of the patch (cm / (side / 2)); intensity = power / "
            "(side / 2)^2, for a 1/d^2 falloff in half-widths",
        },  # fmt: skip
        "shots": _shots(cal, used, judged, result.gains, frontal),
        "holdout": _holdout(cal, used, judged),
        "tileable": None,
        "reference": None,
        "metal": options.metal,
        "provenance": provenance(),
    }
