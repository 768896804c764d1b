"""Synthetic handheld flash shots of the printed frame with a material in its window, for the
tests of ``predict --shots`` (test_models_shots.py).

A shot is made in the frame's plane and then photographed: the sheet (its markers, the strip of
unprinted paper) is a matte card of :data:`PAPER` albedo lit by the flash (Lambert: albedo / pi
times the cosine over the squared distance), the window shows the material rendered by the
project's renderer under the shot's camera and flash (patch half-widths), and the table around
the sheet is a dark texture under the same light. Each photo pixel is traced back to the
frame's plane through the pose's homography (supersampled twice, then area-averaged), scaled
by the shot's exposure, clipped, sRGB-encoded and saved as an 8-bit PNG."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from svbrdf_models.capture.frame import FrameLayout, draw_frame
from svbrdf_render import SVBRDF, Camera, PointLight, Scene, linear_to_srgb, render

#: The sheet's paper albedo, and the printed ink's.
PAPER, INK = 0.8, 0.03
#: The sheet is drawn at this resolution before it is photographed.
DPI = 100
#: The synthetic photos: size and focal length (pixels); the phone's flash beside its lens (cm).
PHOTO_SIZE, FOCAL = (800, 600), 650.0
FLASH_OFFSET = (1.0, 0.0)


def look_at(camera_cm, up=(0.0, 1.0, 0.0)):
    """OpenCV's rotation (frame -> camera: x right, y down, z forward) and translation of a
    camera at ``camera_cm`` looking at the window's centre, ``up`` shown up in the photo."""
    c = np.asarray(camera_cm, dtype=np.float64)
    z = -c / np.linalg.norm(c)
    up = np.asarray(up, dtype=np.float64)
    y = -(up - up.dot(z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    rot = np.stack([x, y, z])
    return rot, -rot @ c


@dataclass(frozen=True)
class ShotTruth:
    """Where a synthetic shot was taken from (frame cm) and its flash (patch half-widths)."""

    camera_cm: np.ndarray
    flash_cm: np.ndarray
    intensity: float  # for positions in half-widths of the window
    exposure: float

    def camera(self, layout: FrameLayout) -> torch.Tensor:
        return torch.tensor(self.camera_cm / layout.half_width_cm, dtype=torch.float32)

    def flash(self, layout: FrameLayout) -> torch.Tensor:
        return torch.tensor(self.flash_cm / layout.half_width_cm, dtype=torch.float32)

    def scene(self, layout: FrameLayout) -> Scene:
        """The shot's scene in patch units, its exposure folded into the intensity."""
        light = PointLight(self.flash(layout), self.intensity * self.exposure)
        return Scene(Camera(self.camera(layout)), (light,))


@functools.lru_cache(maxsize=4)
def _page_albedo(layout: FrameLayout) -> np.ndarray:
    grey = np.asarray(draw_frame(layout, DPI), dtype=np.float32) / 255
    return INK + (PAPER - INK) * grey


def shot(
    maps: SVBRDF,
    camera_cm,
    *,
    layout: FrameLayout | None = None,
    intensity: float = 60.0,
    exposure: float = 1.0,
    up=(0.0, 1.0, 0.0),
    seed: int = 0,
    strip_scale: float = 1.0,
    size=PHOTO_SIZE,
    focal: float = FOCAL,
):
    """A synthetic shot ``(H, W, 3) uint8`` (sRGB) of ``maps`` in the frame's window, and its truth.
    ``intensity`` is for positions in half-widths; ``strip_scale`` brightens the strip's paper
    alone (a clipped strip)."""
    layout = layout or FrameLayout()
    half = layout.half_width_cm
    w, h = size
    rot, t = look_at(camera_cm, up)
    camera_cm = np.asarray(camera_cm, dtype=np.float64)
    flash_cm = camera_cm + rot.T @ np.array([FLASH_OFFSET[0], -FLASH_OFFSET[1], 0.0])
    truth = ShotTruth(camera_cm, flash_cm, intensity, exposure)
    ss = 2
    k = np.array([[focal * ss, 0, (w * ss - 1) / 2], [0, focal * ss, (h * ss - 1) / 2], [0, 0, 1]])
    to_photo = k @ np.column_stack([rot[:, 0], rot[:, 1], t])  # frame cm (z = 0) -> big photo px
    u, v = np.meshgrid(np.arange(w * ss, dtype=np.float32), np.arange(h * ss, dtype=np.float32))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones_like(u.ravel())])
    plane = np.linalg.inv(to_photo).astype(np.float32) @ pixels
    x, y = (plane[:2] / plane[2]).reshape(2, h * ss, w * ss)
    radiance = _sheet(layout, x, y, flash_cm, intensity * half**2, seed, strip_scale)
    inside = (np.abs(x) < half) & (np.abs(y) < half)
    window = _window(maps, truth.scene(layout), x[inside] / half, y[inside] / half) / exposure
    radiance[inside] = window
    photo = radiance.reshape(h, ss, w, ss, 3).mean(axis=(1, 3)) * exposure
    rng = np.random.default_rng(seed)
    encoded = linear_to_srgb(torch.from_numpy(np.clip(photo, 0, 1)).float()).numpy()
    noisy = np.clip(encoded * 255 + rng.normal(0, 0.8, encoded.shape), 0, 255)
    return np.round(noisy).astype(np.uint8), truth


def _sheet(layout, x, y, flash_cm, intensity_cm, seed, strip_scale) -> np.ndarray:
    """``(H, W, 3)`` radiance of the sheet and the table at frame points ``(x, y)`` cm."""
    page = _page_albedo(layout)
    scale = DPI / 2.54
    ox, oy = layout.origin_on_page_cm
    col = np.floor((x + ox) * scale).astype(int)
    row = np.floor((oy - y) * scale).astype(int)
    on = (col >= 0) & (col < page.shape[1]) & (row >= 0) & (row < page.shape[0])
    rng = np.random.default_rng(seed + 1000)
    table = rng.uniform(0.05, 0.12, size=(64, 64))
    albedo = table[(np.floor(y).astype(int)) % 64, (np.floor(x).astype(int)) % 64]
    albedo = np.where(on, page[row.clip(0, page.shape[0] - 1), col.clip(0, page.shape[1] - 1)], albedo)
    x0, y0, x1, y1 = layout.strip_rect
    strip = (x > x0) & (x < x1) & (y > y0) & (y < y1)
    albedo = np.where(strip, albedo * strip_scale, albedo)
    dx, dy, dz = flash_cm[0] - x, flash_cm[1] - y, flash_cm[2]
    d2 = dx * dx + dy * dy + dz * dz
    shading = intensity_cm * (dz / np.sqrt(d2)) / d2 / math.pi
    return np.repeat((albedo * shading).astype(np.float32)[..., None], 3, axis=-1)


def _window(maps: SVBRDF, scene: Scene, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The material's rendering under ``scene`` at patch points ``(x, y)`` (bilinear in a
    rendering at 4 times the maps' side): ``(N, 3)``."""
    side = 4 * maps.size[0]
    image = render(maps.resize(side, side), scene)  # (1, 3, S, S), row 0 at y = +1
    grid = torch.from_numpy(np.stack([x, -y], axis=-1)).float()[None, None]  # (1, 1, N, 2)
    out = F.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[0, :, 0].T.numpy()


def save(path, photo: np.ndarray, *, focal_35mm: float | None = None) -> None:
    """``photo`` as a PNG, or a JPEG with the 35 mm equivalent focal length in its EXIF."""
    image = Image.fromarray(photo)
    if focal_35mm is None:
        image.save(path)
        return
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = int(round(focal_35mm))
    image.save(path, quality=95, exif=exif)


def focal_35mm(size=PHOTO_SIZE, focal: float = FOCAL) -> float:
    """The 35 mm equivalent focal length of a photo of ``size`` with ``focal`` pixels."""
    return focal * math.hypot(36.0, 24.0) / math.hypot(*size)


def fov(size=PHOTO_SIZE, focal: float = FOCAL) -> float:
    """The field of view across the longer side (degrees) of ``focal`` pixels."""
    return math.degrees(2 * math.atan(max(size) / 2 / focal))
