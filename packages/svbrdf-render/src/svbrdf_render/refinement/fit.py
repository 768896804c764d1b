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

__all__ = ["CARD_F0", "CARD_ROUGHNESS", "FLASH_MODES", "FlashFit", "ReferenceFlash", "axis_flash", "card_maps",
           "fit_flash", "flash_scene", "reference_flash"]

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
    start: SVBRDF, photo: Tensor, distance: float = DES18_DISTANCE, over: Tensor | None = None,
    *, position: Tensor | None = None,
) -> Scene:
    """The Des18 capture (camera and flash on the axis at ``distance``) with the intensity that
    makes ``start`` explain ``photo`` best in the log domain: the median over the pixels of
    ``log(photo) - log(rendering at intensity 1)``, one intensity per material. With ``over``
    ``(B, 2)``, camera and flash stand at ``distance`` above those points of the patch instead
    (a phone held off-centre: :func:`svbrdf_render.refinement.rings.highlight_point` finds the point).
    With ``position`` ``(3,)`` or ``(B, 3)``, camera and flash stand there (the camera's place
    known from the photo's lens and crop), and ``distance`` and ``over`` are not used.

    The median ignores what the start maps get most wrong (the highlight, where a network's
    specular lobe is often off, and clipped pixels); a least-squares intensity is dominated
    by exactly those pixels (on des18-dev it is off by a factor 2-15 even from the true maps).
    """
    b = photo.shape[0]
    if position is not None:
        position = torch.as_tensor(position).to(photo).reshape(-1, 3).expand(b, 3)
        unit = render(start, _camera_flashes(position, photo.new_ones(b)))
    elif over is None:
        position = photo.new_tensor([0.0, 0.0, distance]).expand(b, 3)
        unit = render(start, Scene.flash(distance, 1.0).to(photo.device))
    else:
        position = photo.new_tensor([0.0, 0.0, distance]).expand(b, 3)
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


def _camera_flashes(position: Tensor, intensity: Tensor, color: Tensor | None = None) -> Scene:
    """A light at ``position`` ``(B, 3)`` with the camera at it, of ``intensity`` ``(B,)`` (and
    ``color`` ``(B, 3)``: white when None), one per material: a scene of shape ``()`` for one
    material, ``(B, 1)`` for more."""
    if position.shape[0] == 1:
        extra = () if color is None else (color[0],)
        return Scene(Camera(position[0]), (PointLight(position[0], float(intensity[0]), *extra),), DES18_EFFECTS)
    pos = position[:, None, :]
    extra = () if color is None else (color[:, None, :],)
    return Scene(Camera(pos), (PointLight(pos, intensity[:, None], *extra),), DES18_EFFECTS)


def flash_scene(position: Tensor, intensity: Tensor, color: Tensor | None = None) -> Scene:
    """The capture of :func:`refine_maps`: camera and flash at ``position`` ``(B, 3)`` (patch
    half-widths), flash ``intensity`` ``(B,)`` and ``color`` ``(B, 3)`` (white when None)."""
    return _camera_flashes(position, intensity, color)


# -- a region of known albedo: the flash measured, not guessed -----------------------------------

#: A matte reference card (a grey card, printer paper) as maps: flat, rough, with the small
#: specular of a non-metal. Its diffuse map is ``albedo / (1 - CARD_F0)`` so that what the
#: Des18 diffuse term reflects, ``d (1 - s) / pi``, is the stated albedo over pi.
CARD_F0 = 0.04
CARD_ROUGHNESS = 0.9


def card_maps(albedo: float, size: tuple[int, int], batch: int = 1, device=None) -> SVBRDF:
    """Maps of a matte card of ``albedo`` (its diffuse reflectance), ``size`` pixels."""
    h, w = size
    full = lambda c, v: torch.full((batch, c, h, w), float(v), device=device)  # noqa: E731
    normal = torch.zeros(batch, 3, h, w, device=device)
    normal[:, 2] = 1.0
    return SVBRDF(normal, full(3, min(1.0, albedo / (1 - CARD_F0))), full(1, CARD_ROUGHNESS), full(3, CARD_F0))


@dataclass(frozen=True)
class ReferenceFlash:
    """What :func:`reference_flash` measured, one entry per photo.

    Attributes:
        intensity: ``(B,)`` the flash intensity (luminance of the per-channel gains).
        color: ``(B, 3)`` the flash's colour as the photo shows it (per-channel gain over
            ``intensity``): a grey card measures the white balance too.
        clipped: ``(B,)`` share of the region's pixels at or above the saturation level.
        dark: ``(B,)`` share of the region's pixels too dark to read.
        level: ``(B,)`` the region's mean luminance in the photo (linear).
        pixels: ``(B,)`` pixels the intensity was read from.
    """

    intensity: Tensor
    color: Tensor
    clipped: Tensor
    dark: Tensor
    level: Tensor
    pixels: Tensor


_LUMA = (0.2126, 0.7152, 0.0722)


@torch.no_grad()
def reference_flash(photo: Tensor, mask: Tensor, albedo: float, position: Tensor | None,
                    unit: Tensor | None = None) -> ReferenceFlash:  # fmt: skip
    """The flash that shows a matte card of ``albedo`` where ``mask`` is true as ``photo`` does.

    The card is rendered through the renderer's own image formation at unit intensity, with the
    camera and flash at ``position`` ``(B, 3)`` (patch half-widths): each pixel's position in the
    field of view, its distance, cosine and fall-off, and a matte card's small specular
    (:func:`card_maps`). Per channel, the gain is the median of ``photo / unit rendering`` over
    the region's pixels that are neither clipped (at or above 0.98) nor too dark (below 0.002);
    the rendering is linear in the intensity, so that gain is the flash. Nothing is raised: the
    caller judges ``clipped``, ``dark`` and ``pixels``.

    Args:
        photo: ``(B, 3, H, W)`` linear photos.
        mask: ``(B or 1, 1, H, W)`` true over the card.
        albedo: the card's diffuse reflectance in (0, 1].
        position: ``(B, 3)`` or ``(3,)``.
        unit: ``(B, 3, H, W)``: the card's rendering at unit intensity at the photo's pixels,
            when they are not the patch's (a strip beside it, seen by a camera apart from the
            flash): ``position`` is then not used.
    """
    b, _, h, w = photo.shape
    photo = photo.float()
    if unit is None:
        position = position.to(photo).reshape(-1, 3).expand(b, 3)
        card = card_maps(albedo, (h, w), b, photo.device)
        unit = render(card, _camera_flashes(position, photo.new_ones(b)))
        unit = unit[:, 0] if unit.dim() == 5 else unit
    unit = unit.to(photo)
    region = mask.to(photo.device, torch.bool).expand(b, 1, h, w)
    top = photo.amax(1, keepdim=True)
    clipped_px = (top >= _SATURATED) & region
    dark_px = (top < 2 * _DARK) & region
    keep = region & ~clipped_px & ~dark_px & (unit.amin(1, keepdim=True) > 1e-6)
    count = region.flatten(1).sum(1).clamp_min(1).float()
    luma = photo.new_tensor(_LUMA).view(1, 3, 1, 1)
    level = ((photo * luma).sum(1, keepdim=True) * region).flatten(1).sum(1) / count
    gains = torch.ones(b, 3, device=photo.device)
    for i in range(b):
        k = keep[i, 0]
        if k.any():
            gains[i] = (photo[i][:, k] / unit[i][:, k]).median(dim=1).values
    intensity = (gains * luma.view(1, 3)).sum(1)
    color = gains / intensity.clamp_min(1e-12)[:, None]
    return ReferenceFlash(
        intensity, color, clipped_px.flatten(1).sum(1) / count, dark_px.flatten(1).sum(1) / count, level,
        keep.flatten(1).sum(1),
    )
