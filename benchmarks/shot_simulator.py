"""Handheld phone captures, simulated (issue 44): what ``benchmarks/shots.py`` feeds the
whole ``svbrdf-models predict`` command, JPEG files and all.

A material's maps (an :class:`svbrdf_render.SVBRDF`, the patch ``[-1, 1]^2``) lie in a world
whose unit is the patch's half-width, the plane ``z = 0``, x right, y up. Three kinds of shot:

- ``frame``: the printed frame (:class:`svbrdf_models.capture.frame.FrameLayout`, drawn by
  :func:`~svbrdf_models.capture.frame.draw_frame`) lies on the material with its window over
  the patch: paper of albedo :data:`PAPER_ALBEDO` with black markers (matte: flat normal,
  roughness :data:`PAPER_ROUGHNESS`, specular 0.04), the material in the window, a table
  around the sheet;
- ``today``: no frame, the material (extended beyond the patch by mirroring) fills the photo,
  as a user shoots today; the camera stands where the photo's centred square covers about the
  patch (the lens decides it: about 2 half-widths of the square);
- ``card``: the ``today`` shot with an 18% grey card in a corner of the square, its pixel box
  known (:attr:`Shot.card_box`, for ``--reference X,Y,W,H:0.18``).

A shot is drawn (:func:`draw_shot`) as a phone held by hand: camera 1.8-4 window half-widths
from the window's centre (frame shots are redrawn until every marker and the reference strip
are in the picture, which a 26 mm lens allows only from about 3 half-widths), tilted up to 20
degrees, aimed within 0.1 of the centre, rolled up to 10 degrees; the lens 24-28 mm equivalent
(written in the EXIF, FocalLengthIn35mmFilm); the flash about 1 cm beside the lens in the
camera's plane (one offset per phone, :class:`Phone`); auto exposure: the flash's irradiance at
the aim point as in the Des18 photos (intensity 15 at 2.2) times a factor drawn log-uniformly
in [0.5, 2] (frame shots: metered on the white sheet instead, :data:`FRAME_LEVEL`); read and
shot noise; sRGB tone curve; JPEG quality 85-95.

The photo (:func:`make_photo`) is shaded by the project's renderer (``svbrdf_render.render``,
Des18 effects: the radiance of each surface point towards the camera under the flash, 1/d^2
fall-off) on a grid of the plane, in tiles (each tile the renderer's patch: positions divided
by the tile's half-extent, the intensity by its square), at about twice the photo's pixel
density, then projected into the photo by the pinhole camera (the plane's homography,
``cv2.warpPerspective`` to a twice finer grid, then area-averaged: no aliasing).

The truth (:meth:`Shot.to_dict`) is saved beside each photo: camera, flash, intensity (with the
exposure) in world units, rotation, intrinsics.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

__all__ = [
    "CARD_ALBEDO",
    "PAPER_ALBEDO",
    "Phone",
    "Shot",
    "World",
    "draw_phone",
    "draw_shot",
    "make_photo",
    "save_jpeg",
    "square_truth",
    "square_to_world",
    "known_scene",
]

#: The printed sheet: plain paper, black ink, matte.
PAPER_ALBEDO, INK_ALBEDO, PAPER_ROUGHNESS, PAPER_F0 = 0.8, 0.04, 0.9, 0.04
#: The table around the sheet (albedo range of its blotches), matte-ish.
TABLE_ALBEDO, TABLE_ROUGHNESS = (0.08, 0.25), 0.6
#: The grey card of the ``card`` shot.
CARD_ALBEDO = 0.18
#: The handheld draw.
DISTANCE_RANGE = (1.8, 4.0)  # window half-widths from the window's centre
MAX_TILT_DEG, MAX_ROLL_DEG, MAX_AIM = 20.0, 10.0, 0.1
EXPOSURE_RANGE = (0.5, 2.0)
JPEG_RANGE = (85, 95)
FOCAL_35MM_RANGE = (24, 28)
#: Auto exposure, before the x0.5-2 draw: without the frame, the flash's irradiance at the aim
#: point as the Des18 photos' (15 at 2.2); with it, metered on the white sheet that fills most of
#: the view: the paper at the aim point would be FRAME_LEVEL (linear), as a phone's meter keeps
#: a white page from clipping.
DES18_INTENSITY, DES18_DISTANCE, FRAME_LEVEL = 15.0, 2.2, 0.5
#: Sensor noise in linear units: sigma^2 = READ^2 + SHOT * value.
READ_NOISE, SHOT_NOISE = 0.002, 2e-4
#: Photos are portrait, 3:4 (W x H as stored and displayed; no EXIF rotation).
ASPECT = 4 / 3
_TILE = 768
_MAX_SHEET_PIXELS = 60e6


@dataclass(frozen=True)
class Phone:
    """What stays the same over one capture's shots: the lens and where the flash is."""

    focal_35mm: int
    flash_offset_cm: tuple[float, float]  # along the photo's x (right) and y (up), as displayed

    def to_dict(self) -> dict:
        return {"focal_35mm": self.focal_35mm, "flash_offset_cm": list(self.flash_offset_cm)}


def draw_phone(rng: np.random.Generator) -> Phone:
    """A phone: 24-28 mm equivalent lens, the flash 0.8-1.2 cm right of the lens, +-0.3 cm up."""
    return Phone(
        int(rng.integers(FOCAL_35MM_RANGE[0], FOCAL_35MM_RANGE[1] + 1)),
        (float(rng.uniform(0.8, 1.2)), float(rng.uniform(-0.3, 0.3))),
    )


@dataclass
class Shot:
    """One simulated photo and its truth. World units: half-widths of the material's patch."""

    kind: str  # "frame", "today" or "card"
    size: tuple[int, int]  # (W, H) pixels
    focal_35mm: int
    focal_px: float
    rotation: np.ndarray  # (3, 3) world -> camera (OpenCV: x right, y down, z forward)
    camera: np.ndarray  # (3,)
    flash: np.ndarray  # (3,)
    intensity: float  # the flash's intensity times the exposure
    exposure: float
    jpeg_quality: int
    tilt_deg: float
    cm_per_unit: float  # physical scale (frame: the window's half-width in cm)
    card: tuple[float, float, float, float] | None = None  # world (cx, cy, half, angle rad)
    card_box: tuple[int, int, int, int] | None = None  # photo pixels (x, y, w, h)

    @property
    def K(self) -> np.ndarray:
        w, h = self.size
        return np.array([[self.focal_px, 0, (w - 1) / 2], [0, self.focal_px, (h - 1) / 2], [0, 0, 1.0]])

    @property
    def homography(self) -> np.ndarray:
        """World plane (x, y) -> photo pixels (centres at integers)."""
        r, t = self.rotation, -self.rotation @ self.camera
        return self.K @ np.column_stack([r[:, 0], r[:, 1], t])

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(self.camera))

    def scene(self):
        """The shot's camera and flash as a renderer scene (world units, exposure included)."""
        from svbrdf_render import DES18_EFFECTS, Camera, PointLight, Scene

        return Scene(
            Camera(torch.tensor(self.camera, dtype=torch.float32)),
            (PointLight(torch.tensor(self.flash, dtype=torch.float32), float(self.intensity)),),
            DES18_EFFECTS,
        )

    def to_dict(self) -> dict:
        d = {
            "kind": self.kind,
            "size": list(self.size),
            "focal_35mm": self.focal_35mm,
            "focal_px": self.focal_px,
            "rotation": self.rotation.tolist(),
            "camera": self.camera.tolist(),
            "flash": self.flash.tolist(),
            "intensity": self.intensity,
            "exposure": self.exposure,
            "jpeg_quality": self.jpeg_quality,
            "tilt_deg": self.tilt_deg,
            "distance": self.distance,
            "cm_per_unit": self.cm_per_unit,
        }
        if self.card_box is not None:
            d["card"] = list(self.card)
            d["card_box"] = list(self.card_box)
        return d


def _apply(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ h.T
    return p[:, :2] / p[:, 2:3]


def _look_at(camera: np.ndarray, aim: np.ndarray, roll: float) -> np.ndarray:
    """World -> camera rotation (rows: the camera's x right, y down, z forward in the world)."""
    z = aim - camera
    z /= np.linalg.norm(z)
    up = np.array([-math.sin(roll), math.cos(roll), 0.0])
    y = -(up - up.dot(z) * z)
    y /= np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z])


def photo_size(short: int) -> tuple[int, int]:
    """(W, H) of a portrait 3:4 photo whose shorter side is ``short``."""
    return int(short), int(round(short * ASPECT))


def _frame_outline(layout) -> np.ndarray:
    """(N, 2) world points that must be in a frame shot: every marker's corners, the strip's."""
    pts = np.concatenate([layout.marker_corners.reshape(-1, 2), layout.strip_corners])
    return pts / layout.half_width_cm


def draw_shot(rng: np.random.Generator, phone: Phone, short: int, kind: str = "frame", layout=None,
              *, tries: int = 2000) -> Shot:  # fmt: skip
    """A handheld shot of ``kind`` (``frame``, ``today`` or ``card``) for a photo ``short``
    pixels on its shorter side (portrait 3:4). ``layout``: the frame (default 10 cm)."""
    if kind not in ("frame", "today", "card"):
        raise ValueError(f"kind must be frame, today or card, got {kind!r}")
    if layout is None:
        from svbrdf_models.capture.frame import FrameLayout

        layout = FrameLayout()
    w, h = photo_size(short)
    focal_px = phone.focal_35mm * math.hypot(w, h) / math.hypot(36.0, 24.0)
    margin = 0.015 * w
    outline = _frame_outline(layout)
    for _ in range(tries):
        distance = float(rng.uniform(*DISTANCE_RANGE))
        tilt = math.radians(MAX_TILT_DEG) * math.sqrt(float(rng.uniform()))
        azimuth = float(rng.uniform(0, 2 * math.pi))
        roll = math.radians(float(rng.uniform(-MAX_ROLL_DEG, MAX_ROLL_DEG)))
        aim = np.array([*rng.uniform(-MAX_AIM, MAX_AIM, 2), 0.0])
        exposure = math.exp(float(rng.uniform(math.log(EXPOSURE_RANGE[0]), math.log(EXPOSURE_RANGE[1]))))
        quality = int(rng.integers(JPEG_RANGE[0], JPEG_RANGE[1] + 1))
        cm_per_unit = layout.half_width_cm
        if kind != "frame":
            # no frame: the material fills the photo; the camera where the centred square spans
            # about the patch. The physical distance is the drawn one (the flash's offset in cm).
            physical_cm = distance * layout.half_width_cm
            distance = focal_px / (min(w, h) / 2)
            cm_per_unit = physical_cm / distance
        st = math.sin(tilt)
        direction = np.array([st * math.cos(azimuth), st * math.sin(azimuth), math.cos(tilt)])
        camera = aim + distance * direction
        rot = _look_at(camera, aim, roll)
        shot = Shot(kind, (w, h), phone.focal_35mm, focal_px, rot, camera, camera.copy(), 0.0, exposure,
                    quality, math.degrees(tilt), cm_per_unit)  # fmt: skip
        if kind == "frame":
            px = _apply(shot.homography, outline)
            inside = (px >= margin).all() and (px[:, 0] <= w - 1 - margin).all()
            if not (inside and (px[:, 1] <= h - 1 - margin).all()):
                continue
        dx, dy = phone.flash_offset_cm
        flash = camera + rot.T @ np.array([dx, -dy, 0.0]) / cm_per_unit
        shot.flash = flash
        des18 = DES18_INTENSITY / DES18_DISTANCE**2
        level = FRAME_LEVEL / (PAPER_ALBEDO / math.pi) if kind == "frame" else des18
        shot.intensity = level * float(np.linalg.norm(flash - aim)) ** 2 * exposure
        if kind == "card":
            _place_card(shot)
        return shot
    raise RuntimeError(f"no {kind} shot with the whole frame in view after {tries} draws")


# --- the square of a today/card photo ---------------------------------------------------------
def square_box(size: tuple[int, int]) -> tuple[int, int, int]:
    """(x0, y0, side) of the centred square a capture takes (as the capture computes it)."""
    w, h = size
    side = min(w, h)
    return (w - side) // 2, (h - side) // 2, side


def _square_uv_to_photo(size, uv: np.ndarray) -> np.ndarray:
    """Square coordinates (u right, v up in [-1, 1]) -> photo pixels (centres at integers)."""
    x0, y0, side = square_box(size)
    return np.stack([x0 + (uv[:, 0] + 1) / 2 * side - 0.5, y0 + (1 - uv[:, 1]) / 2 * side - 0.5], axis=1)


def square_to_world(shot: Shot, uv: np.ndarray) -> np.ndarray:
    """(N, 2) square coordinates of the photo's centred square -> (N, 2) world points."""
    return _apply(np.linalg.inv(shot.homography), _square_uv_to_photo(shot.size, uv))


def world_to_square(shot: Shot, xy: np.ndarray) -> np.ndarray:
    x0, y0, side = square_box(shot.size)
    px = _apply(shot.homography, xy)
    return np.stack([(px[:, 0] + 0.5 - x0) / side * 2 - 1, 1 - (px[:, 1] + 0.5 - y0) / side * 2], axis=1)


def _similarity(shot: Shot) -> tuple[complex, complex]:
    """(a, b): the least-squares similarity world = a * square + b (complex numbers)."""
    g = np.linspace(-1, 1, 9)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = square_to_world(shot, uv)
    z, w = uv[:, 0] + 1j * uv[:, 1], xy[:, 0] + 1j * xy[:, 1]
    zm, wm = z.mean(), w.mean()
    a = np.sum(np.conj(z - zm) * (w - wm)) / np.sum(np.abs(z - zm) ** 2)
    return complex(a), complex(wm - a * zm)


def _place_card(shot: Shot) -> None:
    """An 18% card, a square on the surface aligned with the photo, in the square's top-left
    corner (about a fifth of its side); its pixel box: inside its image, 1 px in."""
    a, _ = _similarity(shot)
    x0, y0, side = square_box(shot.size)
    centre_px = np.array([[x0 + 0.14 * side, y0 + 0.14 * side]])
    centre = _apply(np.linalg.inv(shot.homography), centre_px)[0]
    half = 0.2 * abs(a)  # a fifth of the square's side (2 units of square: side = 2|a|)
    angle = math.atan2(a.imag, a.real)
    shot.card = (float(centre[0]), float(centre[1]), float(half), angle)
    c, s = math.cos(angle), math.sin(angle)
    square = np.array([(-half, half), (half, half), (half, -half), (-half, -half)])
    corners = square @ np.array([[c, s], [-s, c]])
    px = _apply(shot.homography, corners + centre)  # TL, TR, BR, BL in the photo
    left, right = max(px[0, 0], px[3, 0]) + 1, min(px[1, 0], px[2, 0]) - 1
    top, bottom = max(px[0, 1], px[1, 1]) + 1, min(px[2, 1], px[3, 1]) - 1
    x, y = math.ceil(left + 0.5), math.ceil(top + 0.5)  # pixel x covers [x - 0.5, x + 0.5)
    shot.card_box = (x, y, max(1, math.floor(right - 0.5) - x), max(1, math.floor(bottom - 0.5) - y))


def known_scene(shot: Shot):
    """The true flash of a today/card shot in its square's units (best similarity): the scene
    of ``--scene`` for a capture that knew it (camera, flash, intensity with the exposure)."""
    from svbrdf_render import DES18_EFFECTS, Camera, PointLight, Scene

    a, b = _similarity(shot)

    def to_square(p):
        z = (complex(p[0], p[1]) - b) / a
        return torch.tensor([z.real, z.imag, p[2] / abs(a)], dtype=torch.float32)

    return Scene(
        Camera(to_square(shot.camera)),
        (PointLight(to_square(shot.flash), float(shot.intensity / abs(a) ** 2)),),
        DES18_EFFECTS,
    )


# --- the world's maps -------------------------------------------------------------------------
def _fold(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror ``t`` into [-1, 1] (period 4); and -1 where mirrored an odd number of times."""
    k = torch.floor((t + 1) / 2)
    r = t - 2 * k
    odd = torch.remainder(k, 2) == 1
    return torch.where(odd, -r, r), torch.where(odd, -1.0, 1.0)


class World:
    """The surface a shot sees: maps at any world points.

    ``material``: the patch's maps (an SVBRDF, batch 1). ``frame``: draw the printed frame
    around it (else the material, mirrored, everywhere). ``card``: (cx, cy, half, angle), an
    18% card on top."""

    def __init__(self, material, frame: bool, layout=None, *, dpi: float = 150, card=None, seed: int = 0):
        m = material.detach().to(torch.float32)
        self.packed = torch.cat([m.normal, m.diffuse, m.roughness, m.specular], dim=1)[:1]
        self.frame, self.card = frame, card
        if frame:
            from svbrdf_models.capture.frame import FrameLayout, draw_frame

            self.layout = layout or FrameLayout()
            self.dpi = int(round(dpi))
            page = np.asarray(draw_frame(self.layout, self.dpi), dtype=np.float32) / 255
            self.page = torch.from_numpy(page)[None, None]
            g = torch.Generator().manual_seed(seed)
            self.table = torch.rand(1, 3, 12, 12, generator=g)  # blotches over [-8, 8]^2

    @staticmethod
    def _sample(image: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor, padding: str) -> torch.Tensor:
        grid = torch.stack([gx, gy], dim=-1)[None].to(image.dtype)
        return F.grid_sample(image, grid, mode="bilinear", padding_mode=padding, align_corners=False)[0]

    def maps(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """(10, H, W): normal, diffuse, roughness, specular at the world points ``x``, ``y``."""
        if self.frame:
            fx, fy, sx, sy = x, y, torch.ones_like(x), torch.ones_like(y)
        else:
            (fx, sx), (fy, sy) = _fold(x), _fold(y)
        m = self._sample(self.packed, fx, -fy, "border")
        n = m[:3] * torch.stack([sx, sy, torch.ones_like(sx)])
        m = torch.cat([n / n.norm(dim=0, keepdim=True).clamp_min(1e-6), m[3:]])
        if self.frame:
            m = self._with_sheet(m, x, y)
        if self.card is not None:
            cx, cy, half, angle = self.card
            c, s = math.cos(angle), math.sin(angle)
            u = (x - cx) * c + (y - cy) * s
            v = -(x - cx) * s + (y - cy) * c
            on = (u.abs() <= half) & (v.abs() <= half)
            m = torch.where(on[None], _flat_maps(CARD_ALBEDO / (1 - PAPER_F0), 0.85, PAPER_F0, x.shape), m)
        return m

    def _with_sheet(self, m: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        layout, per_cm = self.layout, self.dpi / 2.54
        half = layout.half_width_cm
        ox, oy = layout.origin_on_page_cm
        hp, wp = self.page.shape[-2:]
        u = (ox + x * half) * per_cm  # page pixels (continuous, pixel 0 covers [0, 1))
        v = (oy - y * half) * per_cm
        gx, gy = 2 * u / wp - 1, 2 * v / hp - 1
        grey = self._sample(self.page, gx, gy, "border")[0]
        on_paper = (gx.abs() <= 1) & (gy.abs() <= 1)
        albedo = INK_ALBEDO + (PAPER_ALBEDO - INK_ALBEDO) * grey
        paper = _flat_maps(0.0, PAPER_ROUGHNESS, PAPER_F0, x.shape)
        paper[3:6] = albedo / (1 - PAPER_F0)
        blot = self._sample(self.table, x / 8, -y / 8, "border")
        table = _flat_maps(0.0, TABLE_ROUGHNESS, PAPER_F0, x.shape)
        lo, hi = TABLE_ALBEDO
        table[3:6] = lo + (hi - lo) * blot * torch.tensor([1.0, 0.8, 0.6])[:, None, None]
        window = (x.abs() < 1) & (y.abs() < 1)
        out = torch.where(on_paper[None], paper, table)
        return torch.where(window[None], m, out)


def _flat_maps(albedo: float, roughness: float, f0: float, shape) -> torch.Tensor:
    h, w = shape
    out = torch.empty(10, h, w)
    out[0:2], out[2] = 0.0, 1.0
    out[3:6], out[6], out[7:10] = albedo, roughness, f0
    return out


def _unpack(m: torch.Tensor):
    from svbrdf_render import SVBRDF

    m = m[None]
    return SVBRDF(m[:, 0:3], m[:, 3:6], m[:, 6:7], m[:, 7:10], validate=False)


# --- the photo --------------------------------------------------------------------------------
def _footprint(shot: Shot, pad: float) -> tuple[np.ndarray, float]:
    """(x0, x1, y0, y1) world box the photo sees (its corners back-projected, ``pad`` px more),
    and the smallest depth of those points (camera z)."""
    w, h = shot.size
    lo, right, bottom = -pad, w - 1 + pad, h - 1 + pad
    corners = np.array([(lo, lo), (right, lo), (right, bottom), (lo, bottom)], float)
    xy = _apply(np.linalg.inv(shot.homography), corners)
    depth = (shot.rotation @ (np.concatenate([xy, np.zeros((4, 1))], 1) - shot.camera).T)[2]
    return np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()]), float(depth.min())


def render_sheet(world: World, shot: Shot, box, rho: float, tile: int = _TILE) -> np.ndarray:
    """(H, W, 3) linear radiance towards the shot's camera over the world ``box`` (x0, x1, y0,
    y1), ``rho`` pixels per unit, rendered in tiles (each tile the renderer's patch)."""
    from svbrdf_render import render
    from svbrdf_render.geometry import surface_positions

    x0, x1, y0, y1 = box
    cols, rows = int(math.ceil((x1 - x0) * rho)), int(math.ceil((y1 - y0) * rho))
    out = np.empty((rows, cols, 3), np.float32)
    grid = surface_positions(tile, tile)
    e = tile / (2 * rho)
    scene = shot.scene()
    cam, light = scene.camera.position, scene.point_lights[0]
    from svbrdf_render import DES18_EFFECTS, Camera, PointLight, Scene

    with torch.no_grad():
        for i0 in range(0, rows, tile):
            for j0 in range(0, cols, tile):
                cx, cy = x0 + (j0 + tile / 2) / rho, y1 - (i0 + tile / 2) / rho
                centre = torch.tensor([cx, cy, 0.0])
                maps = _unpack(world.maps(cx + e * grid[0], cy + e * grid[1]))
                local = Scene(
                    Camera((cam - centre) / e),
                    (PointLight((light.position - centre) / e, float(light.intensity) / e**2),),
                    DES18_EFFECTS,
                )
                img = render(maps, local)[0].permute(1, 2, 0).numpy()
                r, c = min(tile, rows - i0), min(tile, cols - j0)
                out[i0 : i0 + r, j0 : j0 + c] = img[:r, :c]
    return out


def make_photo(world: World, shot: Shot, rng: np.random.Generator, *, supersample: int = 2) -> np.ndarray:
    """The shot's photo: (H, W, 3) uint8, sRGB-encoded, with noise (before JPEG)."""
    import cv2

    w, h = shot.size
    ss = int(supersample)
    box, depth = _footprint(shot, pad=4.0)
    rho = ss * shot.focal_px / depth * 1.1
    area = (box[1] - box[0]) * (box[3] - box[2]) * rho * rho
    if area > _MAX_SHEET_PIXELS:
        rho *= math.sqrt(_MAX_SHEET_PIXELS / area)
    sheet = render_sheet(world, shot, box, rho)
    x0, _, _, y1 = box
    to_world = np.array([[1 / rho, 0, x0 + 0.5 / rho], [0, -1 / rho, y1 - 0.5 / rho], [0, 0, 1]])
    up = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    big = cv2.warpPerspective(sheet, up @ shot.homography @ to_world, (w * ss, h * ss),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    del sheet
    linear = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) if ss > 1 else big
    sigma = np.sqrt(READ_NOISE**2 + SHOT_NOISE * np.clip(linear, 0, None))
    linear = np.clip(linear + sigma * rng.standard_normal(linear.shape).astype(np.float32), 0, 1)
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    return np.clip(np.round(encoded * 255), 0, 255).astype(np.uint8)


def save_jpeg(photo: np.ndarray, shot: Shot, path) -> Path:
    """Write ``photo`` as a JPEG at the shot's quality, its lens in the EXIF
    (FocalLengthIn35mmFilm, Exif IFD 0x8769 tag 0xA405), and the truth beside it (``.json``)."""
    from PIL import Image

    path = Path(path)
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = int(shot.focal_35mm)
    Image.fromarray(photo).save(path, "JPEG", quality=int(shot.jpeg_quality), exif=exif.tobytes())
    path.with_suffix(".json").write_text(json.dumps(shot.to_dict(), indent=1))
    return path


def square_truth(world: World, shot: Shot, n: int):
    """The truth of a today/card shot's square, ``n`` px: the world's maps under the photo's
    centred square (normals turned into the square's axes), and (1, 1, n, n) true over the card."""
    g = (torch.arange(n, dtype=torch.float64) * 2 + 1) / n - 1
    vv, uu = torch.meshgrid(-g, g, indexing="ij")
    uv = np.stack([uu.numpy().ravel(), vv.numpy().ravel()], 1)
    xy = torch.from_numpy(square_to_world(shot, uv)).float()
    x, y = xy[:, 0].reshape(n, n), xy[:, 1].reshape(n, n)
    m = world.maps(x, y)
    a, _ = _similarity(shot)
    c, s = a.real / abs(a), a.imag / abs(a)  # the square's u axis in the world
    nx, ny = m[0] * c + m[1] * s, -m[0] * s + m[1] * c
    m = torch.cat([torch.stack([nx, ny, m[2]]), m[3:]])
    card = torch.zeros(1, 1, n, n, dtype=torch.bool)
    if world.card is not None:
        cx, cy, half, angle = world.card
        cc, ss = math.cos(angle), math.sin(angle)
        u, v = (x - cx) * cc + (y - cy) * ss, -(x - cx) * ss + (y - cy) * cc
        card[0, 0] = (u.abs() <= half) & (v.abs() <= half)
    return _unpack(m), card


def square_maps_to_window(maps, shot: Shot, n: int):
    """Maps of a today/card shot's square (an SVBRDF) resampled onto the patch ``[-1, 1]^2``
    at ``n`` px (normals turned back into the world's axes), and (1, 1, n, n) true where the
    square covers the patch: to relight them like a frame capture's maps."""
    from svbrdf_render import SVBRDF

    g = (torch.arange(n, dtype=torch.float64) * 2 + 1) / n - 1
    yy, xx = torch.meshgrid(-g, g, indexing="ij")
    xy = np.stack([xx.numpy().ravel(), yy.numpy().ravel()], 1)
    uv = torch.from_numpy(world_to_square(shot, xy)).float().reshape(n, n, 2)
    inside = (uv.abs() <= 1).all(-1)
    packed = torch.cat([maps.normal, maps.diffuse, maps.roughness, maps.specular], 1)[:1].float()
    grid = torch.stack([uv[..., 0], -uv[..., 1]], -1)[None]
    m = F.grid_sample(packed, grid, mode="bilinear", padding_mode="border", align_corners=False)[0]
    a, _ = _similarity(shot)
    c, s = a.real / abs(a), a.imag / abs(a)
    nx, ny = m[0] * c - m[1] * s, m[0] * s + m[1] * c
    n3 = torch.stack([nx, ny, m[2]])
    n3 = n3 / n3.norm(dim=0, keepdim=True).clamp_min(1e-6)
    m = torch.cat([n3, m[3:]])[None]
    return SVBRDF(m[:, 0:3], m[:, 3:6], m[:, 6:7], m[:, 7:10], validate=False), inside[None, None]
