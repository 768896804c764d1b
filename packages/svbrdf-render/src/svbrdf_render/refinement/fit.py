"""Fit a flash to a photo through the renderer.

Given maps and a photo of them under a flash, find the flash position and intensity that
best re-render the photo. By default the camera travels with the flash (a phone: lens and
flash a centimetre apart); ``colocated=False`` keeps the camera on the axis at
``camera_distance`` and moves the light alone. The intensity is solved in closed form at every step (the
rendering is linear in it), so gradient descent moves only the three coordinates of the
light. The resulting RMSE is how re-renderings of real photos are judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ..compare import per_sample_rmse
from ..effects import DES18_EFFECTS
from ..errors import MapError
from ..maps import SVBRDF
from ..renderer import render
from ..scene import DES18_DISTANCE, Camera, PointLight, Scene

__all__ = ["FLASH_MODES", "FlashFit", "axis_flash", "fit_flash"]

#: Pixels at or above this are taken as clipped by the camera; below _DARK as too dark to
#: tell anything (and kept away from log(0)).
_SATURATED, _DARK = 0.98, 1e-3


@dataclass(frozen=True)
class FlashFit:
    """Result of :func:`fit_flash`, one entry per material.

    Attributes:
        position: ``(B, 3)`` fitted light positions.
        intensity: ``(B,)`` fitted intensities.
        rmse: ``(B,)`` RMSE of the clipped re-rendering against the photo, at full size.
        rendering: ``(B, 3, H, W)`` the clipped re-rendering.
        colocated: whether the camera sat at the light (else on the axis at
            ``camera_distance``).
    """

    position: Tensor
    intensity: Tensor
    rmse: Tensor
    rendering: Tensor
    colocated: bool = True
    camera_distance: float = DES18_DISTANCE

    def scene(self, index: int = 0, effects=DES18_EFFECTS) -> Scene:
        """The fitted scene of material ``index``."""
        pos = self.position[index]
        camera = Camera(pos if self.colocated else torch.tensor([0.0, 0.0, self.camera_distance]))
        return Scene(camera, (PointLight(pos, float(self.intensity[index])),), effects)


def _unit_render(svbrdf: SVBRDF, pos: Tensor, colocated: bool, distance: float, effects) -> Tensor:
    pos = pos.unsqueeze(1)  # (B, 1, 3): one configuration per material
    camera = Camera(pos if colocated else pos.new_tensor([0.0, 0.0, distance]))
    return render(svbrdf, Scene(camera, (PointLight(pos, 1.0),), effects))[:, 0]


def _best_intensity(unit: Tensor, photo: Tensor, saturation: float = 0.98) -> Tensor:
    """Least-squares intensity over the unsaturated pixels of the photo.

    Saturated pixels only say "at least this bright"; counting them would pull the
    intensity down whenever the photo clips.
    """
    keep = (photo < saturation).to(unit.dtype)
    num = (unit * photo * keep).flatten(1).sum(1)
    den = (unit * unit * keep).flatten(1).sum(1).clamp_min(1e-12)
    return (num / den).clamp_min(0)


class _Adam:
    """Adam with torch.optim.Adam's defaults and update (betas 0.9 and 0.999, eps 1e-8,
    bias-corrected, a step count per tensor), on one tensor or on torch.optim's parameter
    groups (``[{"params": [...], "lr": ...}]``), without torch.optim: the first torch.optim
    step imports torch._dynamo, about 0.8 s on a CPU, more than a whole flash fit and most of a
    256 px refinement. A tensor without a gradient is left as it is, as torch.optim leaves it."""

    def __init__(self, params: Tensor | list[dict], lr: float | None = None, betas=(0.9, 0.999), eps: float = 1e-8):
        groups = [{"params": [params], "lr": lr}] if isinstance(params, Tensor) else params
        self.betas, self.eps = betas, eps
        #: ``[param, lr, first moment, second moment, steps taken]`` per tensor.
        self.state = [[p, g["lr"], torch.zeros_like(p), torch.zeros_like(p), 0] for g in groups for p in g["params"]]

    def zero_grad(self) -> None:
        for entry in self.state:
            entry[0].grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of each tensor from its ``grad``, which is then cleared."""
        b1, b2 = self.betas
        for entry in self.state:
            param, lr, m, v, t = entry
            g = param.grad
            if g is None:
                continue
            t = entry[4] = t + 1
            m.lerp_(g, 1 - b1)
            v.mul_(b2).addcmul_(g, g, value=1 - b2)
            denom = (v.sqrt() / math.sqrt(1 - b2**t)).add_(self.eps)
            param.addcdiv_(m, denom, value=-lr / (1 - b1**t))
            param.grad = None


def fit_flash(
    svbrdf: SVBRDF,
    photo: Tensor,
    *,
    colocated: bool = True,
    camera_distance: float = DES18_DISTANCE,
    effects=DES18_EFFECTS,
    steps: int = 150,
    lr: float = 0.05,
    fit_size: int | None = 128,
    init_position: Tensor | None = None,
) -> FlashFit:
    """Fit a point light (position and intensity) so that ``render(svbrdf)`` matches ``photo``.

    Args:
        svbrdf: maps of B materials.
        photo: ``(B, 3, H, W)`` linear photos of the same size as the maps.
        colocated: the camera sits at the light (default), else it stays on the axis.
        camera_distance: starting distance of the flash; the camera's when not colocated.
        effects: the shading effects of the re-rendering (no image effects).
        steps, lr: Adam iterations and step size on the light position.
        fit_size: fit on maps resized to this size (faster; the RMSE is reported at full
            size); ``None`` fits at full size.
        init_position: ``(3,)`` or ``(B, 3)``; default ``(0, 0, camera_distance)``.

    The photo and the re-rendering are compared after clipping the rendering to
    ``[0, 1]``, as a camera saturates.
    """
    if photo.dim() == 3:
        photo = photo.unsqueeze(0)
    b, h, w = svbrdf.shape
    if photo.shape != (b, 3, h, w):
        raise MapError(f"fit_flash: photo has shape {tuple(photo.shape)}, expected {(b, 3, h, w)}")
    photo = photo.to(device=svbrdf.device, dtype=torch.float32)
    maps = svbrdf.detach().to(torch.float32)
    target = photo
    if fit_size is not None and min(h, w) > fit_size:
        maps = maps.resize(fit_size)
        target = F.interpolate(photo, size=(fit_size, fit_size), mode="area")
    if init_position is None:
        init_position = torch.tensor([0.0, 0.0, camera_distance])
    pos = init_position.to(svbrdf.device, torch.float32).expand(b, 3).clone().requires_grad_(True)
    opt = _Adam(pos, lr)
    for _ in range(steps):
        unit = _unit_render(maps, pos, colocated, camera_distance, effects)
        k = _best_intensity(unit, target)
        loss = ((unit * k.view(-1, 1, 1, 1)).clamp(0, 1) - target).square().mean()
        loss.backward()
        opt.step()
        with torch.no_grad():  # keep the light above the surface
            pos[:, 2].clamp_(min=0.05)
    with torch.no_grad():
        unit = _unit_render(svbrdf.detach().to(torch.float32), pos, colocated, camera_distance, effects)
        k = _best_intensity(unit, photo)
        rendering = (unit * k.view(-1, 1, 1, 1)).clamp(0, 1)
        rmse = per_sample_rmse(rendering, photo)
    return FlashFit(pos.detach(), k, rmse, rendering, colocated, camera_distance)


#: How :func:`refine_maps` finds the flash when no scene is given.
FLASH_MODES = ("axis", "fit")


def axis_flash(
    start: SVBRDF, photo: Tensor, distance: float = DES18_DISTANCE, over: Tensor | None = None
) -> Scene:
    """The Des18 capture (camera and flash on the axis at ``distance``) with the intensity that
    makes ``start`` explain ``photo`` best in the log domain: the median over the pixels of
    ``log(photo) - log(rendering at intensity 1)``, one intensity per material. With ``over``
    ``(B, 2)``, camera and flash stand at ``distance`` above those points of the patch instead
    (a phone held off-centre: :func:`svbrdf_render.refinement.rings.highlight_point` finds the point).

    The median ignores what the start maps get most wrong (the highlight, where a network's
    specular lobe is often off, and clipped pixels); a least-squares intensity is dominated
    by exactly those pixels (on des18-dev it is off by a factor 2-15 even from the true maps).
    """
    b = photo.shape[0]
    position = photo.new_tensor([0.0, 0.0, distance]).expand(b, 3)
    if over is None:
        unit = render(start, Scene.flash(distance, 1.0).to(photo.device))
    else:
        position = torch.cat([over.to(photo).reshape(-1, 2).expand(b, 2), position[:, 2:]], dim=1)
        unit = render(start, _camera_flashes(position, photo.new_ones(b)))
    unit = unit[:, 0] if unit.dim() == 5 else unit
    keep = (photo < _SATURATED) & (photo > _DARK) & (unit > _DARK)
    ratio = torch.log(photo.clamp_min(_DARK)) - torch.log(unit.clamp_min(_DARK))
    k = []
    for i in range(b):
        r = ratio[i][keep[i]]
        k.append(torch.exp(r.median()) if r.numel() else photo.new_tensor(1.0))
    return _camera_flashes(position, torch.stack(k))


def _camera_flashes(position: Tensor, intensity: Tensor) -> Scene:
    """A light at ``position`` ``(B, 3)`` with the camera at it, of ``intensity`` ``(B,)``, one per
    material: a scene of shape ``()`` for one material, ``(B, 1)`` for more."""
    if position.shape[0] == 1:
        return Scene(Camera(position[0]), (PointLight(position[0], float(intensity[0])),), DES18_EFFECTS)
    pos = position[:, None, :]
    return Scene(Camera(pos), (PointLight(pos, intensity[:, None]),), DES18_EFFECTS)
