"""Captured maps re-rendered: under the flash that best explains their photo (the capture's
self-consistency figure, :func:`flash_consistency`) and under a light circling them (the relit
preview, :func:`relight_frames`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import (
    DES18_DISTANCE,
    DES18_EFFECTS,
    SVBRDF,
    Camera,
    FlashFit,
    PointLight,
    Scene,
    fit_flash,
    linear_to_srgb,
    render,
)

from .figures import image_grid

__all__ = ["FLASH_FIT", "RELIT_FRAMES", "RELIT_SIZE", "flash_consistency", "relight_frames", "relit_grid", "relit_versions"]

#: Frames of the relit preview, and the largest side it is rendered at.
RELIT_FRAMES = 24
RELIT_SIZE = 256
#: How :func:`flash_consistency` fits the flash (:func:`svbrdf_render.fit_flash` options). 60
#: steps at twice fit_flash's step size: on the 21 real-dev photos the RMSE is within 0.0005
#: of 150 steps at 0.05 on 20 of them and lower on the last (a local minimum escaped), in a
#: third of the time.
FLASH_FIT = {"steps": 60, "lr": 0.1, "fit_size": 128}


def flash_consistency(svbrdf: SVBRDF, photo: Tensor, **fit_options) -> FlashFit:
    """Fit a flash so that the maps re-render the photo (:func:`svbrdf_render.fit_flash`).

    ``photo`` is ``(3, H, W)`` or ``(1, 3, H, W)`` linear, resampled (area) to the maps' size if it
    differs. ``FlashFit.rmse`` is the self-consistency figure: how well the maps explain the photo.
    ``fit_options`` override :data:`FLASH_FIT`.
    """
    if photo.dim() == 3:
        photo = photo[None]
    photo = photo.float()
    if tuple(photo.shape[-2:]) != tuple(svbrdf.size):
        photo = F.interpolate(photo, size=tuple(svbrdf.size), mode="area")
    with torch.inference_mode(False), torch.enable_grad():
        return fit_flash(svbrdf.detach().to(torch.float32), photo, **{**FLASH_FIT, **fit_options})


def _relight_raw(svbrdf: SVBRDF, n: int, radius: float, height: float) -> Tensor:
    """``(n, 3, H, W)`` linear renderings of the first material under a point light circling it
    at intensity 1, not clipped."""
    angles = torch.arange(n, dtype=torch.float32) * (2 * math.pi / n)
    pos = torch.stack([radius * angles.cos(), radius * angles.sin(), torch.full_like(angles, height)], -1)
    maps = svbrdf[0].detach().to(torch.float32)
    scene = Scene(Camera(torch.tensor([0.0, 0.0, DES18_DISTANCE])), (PointLight(pos, 1.0),), DES18_EFFECTS)
    return render(maps, scene)[0]  # (n, 3, H, W)


def _expose(frames: Tensor, intensity=None) -> Tensor:
    """Frames scaled by ``intensity`` (None: so that their brightest 1% just reaches 0.9),
    clipped to [0, 1]."""
    if intensity is None:
        sample = frames.flatten()[:: max(1, frames.numel() // 1_000_000)]
        top = float(torch.quantile(sample, 0.99))
        intensity = 0.9 / top if top > 0 else 1.0
    return (frames * float(intensity)).nan_to_num(0.0).clamp(0, 1)


def relight_frames(
    svbrdf: SVBRDF, n: int = RELIT_FRAMES, *, radius: float = 1.5, height: float = 1.6, intensity=None
) -> Tensor:
    """``(n, 3, H, W)`` linear renderings of the first material under a point light circling it.

    The camera stays on the axis at the Des18 distance; the light goes round at ``radius`` from the
    axis and ``height`` above the patch. ``intensity=None`` exposes all frames alike so that their
    brightest 1% just reaches 0.9; values are clipped to [0, 1].
    """
    return _expose(_relight_raw(svbrdf, n, radius, height), intensity)


def relit_versions(versions: list[SVBRDF]) -> Tensor:
    """``(V, RELIT_FRAMES, 3, S, S)``: the relit frames of each version, at the last version's size
    (at most :data:`RELIT_SIZE`), all exposed alike."""
    side = min(RELIT_SIZE, max(versions[-1].size))
    raw = [_relight_raw(v if tuple(v.size) == (side, side) else v.resize(side), RELIT_FRAMES, 1.5, 1.6)
           for v in versions]  # fmt: skip
    return _expose(torch.stack(raw))


def relit_grid(frames: Tensor, names: list[str] | None = None, cols: int = 6) -> Tensor:
    """The relit frames ``(V, n, 3, H, W)`` as a grid: rows of ``cols`` frames; with several
    versions (``names``), one row per version for each group of angles."""
    n = frames.shape[1]
    names = names or [""]
    rows, labels = [], []
    for i in range(0, n, cols):
        for v, name in enumerate(names):
            rows.append(list(linear_to_srgb(frames[v, i : i + cols])))
            labels.append(f"{name} {i * 360 // n}°".strip())
    return image_grid(rows, [f"+{k * 360 // n}°" for k in range(cols)], labels)
