"""Refine maps until they explain a photo: inverse rendering by gradient descent.

A network (or constant maps) gives a start; :func:`refine_maps` then moves the maps through
the differentiable renderer until their rendering under the photo's flash matches the photo,
at the photo's own resolution, while a prior term keeps them near the start::

    from svbrdf_render import refine_maps
    result = refine_maps(photo, start, steps=200)        # flash fitted to the start maps
    result = refine_maps(photo, start, scene=Scene.flash(intensity=15.0), seconds=5.0)
    result.svbrdf                                        # refined maps, photo-sized

The loss, per material (``R`` the rendering clipped to [0, 1] as a camera saturates, ``P``
the photo, ``x`` a map on its stored encoding, normal as ``(n + 1) / 2``)::

    data   = mean | log(R + eps) - log(P + eps) |                  (the rendering loss' log)
    prior  = sum_map w_map * mean | x - x_prior |                  (L1: edges kept, outliers cheap)

The single photo cannot tell a bright diffuse from a highlight, so what may change is bounded
by the parametrisation (see :class:`RefineSettings`): roughness and specular change only by
smooth fields (a coarse grid upsampled), so the highlight must be explained by them or by the
normals, and the diffuse changes at every pixel but pays the prior for it. Every map is reached
through a function whose every value is valid, so no step leaves the valid range and no clamp
stops a gradient:

- normal ``n = normalize(u, v, 1)``: the slopes ``(u, v)`` are free; ``n.z > 0`` always;
- diffuse, specular, roughness ``x = sigmoid(t)`` with ``t`` free (the start clamped into
  ``[1e-4, 1 - 1e-4]`` first, so a start at 0 or 1 has a finite logit).

The optimiser is Adam on the parameters of each map; ``steps`` or ``seconds`` bound it, a
``callback(step, total, loss)`` reports progress. The result is deterministic: nothing in it
is random, so the same inputs give the same maps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from ..errors import MapError, SceneError
from ..geometry import safe_normalize
from ..maps import MAP_NAMES, SVBRDF, stored_value
from ..metalrough import DIELECTRIC_F0
from ..renderer import BACKENDS, log_radiance, render
from ..scene import Flash, Scene
from .fit import FLASH_MODES, _camera_flashes, axis_flash, fit_flash
from .rings import RingBins, ring_penalty

__all__ = [
    "DEFAULT_REFINE_STEPS", "MIN_REFINE_SIDE", "RefineLoss", "RefineSettings", "Refinement", "prior_targets",
    "prior_weights", "refine_maps", "refine_start", "with_prior",
]  # fmt: skip

#: The refinement budget the photo tools use when none is given (chosen from the accuracy
#: curve of ``benchmarks/refine_curve.py``; see docs/measured-refinement.md).
DEFAULT_REFINE_STEPS = 100

#: Photos with a shorter side below this are refused by the photo tools (the renderer itself
#: refines any size; it is tested down to 1x1).
MIN_REFINE_SIDE = 16
#: How far into (0, 1) a start value is moved before its logit is taken.
_EDGE = 1e-4
#: Slope bound of a start normal: ``n.z`` is raised to about 0.05 (87 degrees) at most.
_MAX_SLOPE = 20.0


@dataclass(frozen=True)
class RefineSettings:
    """How :func:`refine_maps` weighs the photo against the prior, and how it steps.

    Attributes:
        lr: Adam step size on the parameters (logits and slopes).
        eps: the ``eps`` of ``log(x + eps)`` in the data term.
        prior: weight of each map's L1 pull toward the prior (stored encodings).
        coarse: side of the grid on which roughness and specular may change (their change is
            that grid upsampled bilinearly); ``0`` lets them change per pixel.
        normal_lr_scale: the normals' step relative to ``lr`` (they are the noisiest to fit).
        rings: weight of the penalty on maps whose means change with the distance to the
            flash (:func:`svbrdf_render.refinement.rings.ring_penalty`: diffuse, roughness, specular and
            the normal's radial slope): a highlight baked into the maps, or a dark hole where
            it was.
        dielectric: a material whose start specular has a mean luminance below this is taken
            as a dielectric: its specular prior is the grey ``DIELECTRIC_F0`` (0.04, the
            reflectance of most non-metals), not the start's; the photo can still move it,
            paying the prior. ``0`` keeps the start's specular as its prior.
        hold: maps held at the start's values, no free parameter of the refinement: e.g.
            ``("specular",)`` for a material known to be a dielectric (``predict --metal none``).
    """

    lr: float = 0.05
    eps: float = 0.01
    prior: dict[str, float] = field(
        default_factory=lambda: {"normal": 2.0, "diffuse": 0.3, "roughness": 0.05, "specular": 0.2}
    )
    coarse: int = 8
    normal_lr_scale: float = 0.5
    rings: float = 3.0
    dielectric: float = 0.1
    hold: tuple[str, ...] = ()

    def __post_init__(self):
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise ValueError(f"refine: lr must be a finite number > 0, got {self.lr}")
        if not self.eps > 0:
            raise ValueError(f"refine: eps must be > 0, got {self.eps}")
        unknown = (set(self.prior) | set(self.hold)) - set(MAP_NAMES)
        if unknown:
            raise ValueError(f"refine: prior or hold of unknown maps {sorted(unknown)}; maps: {MAP_NAMES}")
        if any(not (w >= 0 and math.isfinite(w)) for w in self.prior.values()):
            raise ValueError(f"refine: prior weights must be finite and >= 0, got {self.prior}")
        if not (self.rings >= 0 and math.isfinite(self.rings)):
            raise ValueError(f"refine: rings must be a finite number >= 0, got {self.rings}")
        if not 0 <= self.dielectric <= 1:
            raise ValueError(f"refine: dielectric must be in [0, 1], got {self.dielectric}")
        if self.coarse < 0:
            raise ValueError(f"refine: coarse must be >= 0, got {self.coarse}")


@dataclass(frozen=True)
class Refinement:
    """What :func:`refine_maps` returns.

    Attributes:
        svbrdf: the refined maps, at the photo's size (detached).
        scene: the scene they were refined under (the fitted flash when none was given).
        steps: Adam steps taken.
        seconds: wall time of the refinement, the flash fit included.
        losses: ``(steps,)`` total loss (mean over the batch) before each step.
    """

    svbrdf: SVBRDF
    scene: Scene
    steps: int
    seconds: float
    losses: Tensor


def refine_start(start: SVBRDF, size: tuple[int, int]) -> SVBRDF:
    """``start`` brought to ``size`` (bilinear, normals renormalised): where a network's maps
    at its own resolution begin a refinement at the photo's."""
    if tuple(start.size) == tuple(size):
        return start
    return start.resize(*size)


def _logit(x: Tensor) -> Tensor:
    x = x.clamp(_EDGE, 1 - _EDGE)
    return torch.log(x) - torch.log1p(-x)


def _slopes(normal: Tensor) -> Tensor:
    """``(B, 2, H, W)`` slopes ``(x / z, y / z)`` of normals; grazing or back-facing ones are
    raised to ``n.z`` of about ``1 / _MAX_SLOPE``."""
    n = safe_normalize(normal, dim=1)
    z = n[:, 2:3].clamp_min(1.0 / _MAX_SLOPE)
    return (n[:, 0:2] / z).clamp(-_MAX_SLOPE, _MAX_SLOPE)


def _normal(slopes: Tensor) -> Tensor:
    n = torch.cat([slopes, torch.ones_like(slopes[:, :1])], dim=1)
    return n * torch.rsqrt((n * n).sum(1, keepdim=True))  # length >= 1: always finite


def _view(rendering: Tensor) -> Tensor:
    """``(B, 3, H, W)`` of a rendering of shape ``(B, 1, 3, H, W)`` (one view per material)."""
    return rendering[:, 0] if rendering.dim() == 5 else rendering


class _Parameters:
    """The free tensors behind the four maps, and the maps they give.

    Each map is ``activation(base + change)``: ``base`` is the start's (fixed), ``change`` a grid
    at the map's own size (normal, diffuse: per pixel, plus a 1x1 grid, their mean) or at most
    ``coarse`` on a side (roughness, specular), upsampled bilinearly; a map of ``hold`` has none.
    """

    def __init__(self, start: SVBRDF, coarse: int, hold: tuple[str, ...] = ()):
        b, h, w = start.shape
        self.size = (h, w)
        self.base = {
            "normal": _slopes(start.normal).detach(),
            "diffuse": _logit(start.diffuse).detach(),
            "roughness": _logit(start.roughness).detach(),
            "specular": _logit(start.specular).detach(),
        }
        limit = {"normal": None, "diffuse": None, "roughness": coarse or None, "specular": coarse or None}
        self.delta: dict[str, list[Tensor]] = {}
        for name, base in self.base.items():
            sizes = [] if name in hold else [_grid_size(h, w, limit[name])]
            if limit[name] is None and sizes and sizes[-1] != (1, 1):  # per-pixel maps: a mean change too
                sizes.append((1, 1))
            self.delta[name] = [
                torch.zeros(b, base.shape[1], gh, gw, device=start.device, requires_grad=True)
                for gh, gw in sizes
            ]

    def groups(self, lr: float, normal_scale: float) -> list[dict]:
        """Adam's parameter groups: per-pixel normal changes (at ``lr * normal_scale``), per-pixel
        diffuse changes, and the rest (the grouping of an experiment that lost, kept so that
        Adam's steps stay bit for bit those measured)."""
        detail_n = [d for d in self.delta["normal"] if d.shape[-2:] != (1, 1)]
        detail_d = [d for d in self.delta["diffuse"] if d.shape[-2:] != (1, 1)]
        lobe = [d for name in MAP_NAMES for d in self.delta[name] if d.shape[-2:] == (1, 1)]
        lobe += [d for name in ("roughness", "specular") for d in self.delta[name] if d.shape[-2:] != (1, 1)]
        return [
            {"params": detail_n, "lr": lr * normal_scale},
            {"params": detail_d, "lr": lr},
            {"params": lobe, "lr": lr},
        ]

    def _free(self, name: str) -> Tensor:
        x = self.base[name]
        for d in self.delta[name]:
            if tuple(d.shape[-2:]) not in (self.size, (1, 1)):  # 1x1 broadcasts as it is
                d = F.interpolate(d, size=self.size, mode="bilinear", align_corners=False)
            x = x + d
        return x

    def svbrdf(self) -> SVBRDF:
        return SVBRDF(
            _normal(self._free("normal")),
            torch.sigmoid(self._free("diffuse")),
            torch.sigmoid(self._free("roughness")),
            torch.sigmoid(self._free("specular")),
            validate=False,
        )


def _grid_size(h: int, w: int, finest: int | None) -> tuple[int, int]:
    """The grid of a map's change: ``(h, w)``, or at most ``finest`` on a side."""
    return (h, w) if finest is None else (min(finest, h), min(finest, w))


def _check(photo: Tensor, start: SVBRDF, prior: SVBRDF | None) -> Tensor:
    if not isinstance(photo, Tensor) or photo.dim() not in (3, 4):
        shape = tuple(photo.shape) if isinstance(photo, Tensor) else type(photo).__name__
        raise MapError(f"refine: expected a photo (B, 3, H, W) or (3, H, W), got {shape}")
    if photo.dim() == 3:
        photo = photo[None]
    if photo.shape[1] != 3:
        raise MapError(f"refine: expected 3 colour channels in the photo, got {photo.shape[1]}")
    if photo.shape[0] != start.batch_size:
        raise MapError(f"refine: {photo.shape[0]} photo(s) but start maps of {start.batch_size} material(s)")
    if not bool(torch.isfinite(photo).all()):
        raise MapError("refine: the photo holds NaN or infinite values")
    if prior is not None and prior.batch_size != start.batch_size:
        raise MapError(f"refine: prior maps of {prior.batch_size} material(s), start of {start.batch_size}")
    return photo.float().clamp(0, 1)


def _scene_for(photo: Tensor, start: SVBRDF, scene: Scene | None, flash: str) -> Scene:
    """The scene given (checked), or a flash found from the start maps, one per material:
    ``"axis"`` by :func:`axis_flash`, ``"fit"`` by :func:`fit_flash` (position too)."""
    b = photo.shape[0]
    if scene is None:
        if flash not in FLASH_MODES:
            raise ValueError(f"refine: flash must be one of {FLASH_MODES}, got {flash!r}")
        if flash == "axis":
            return axis_flash(start, photo)
        fit = fit_flash(start, photo)
        return _camera_flashes(fit.position, fit.intensity)
    if not isinstance(scene, Scene):
        raise SceneError(f"refine: expected a Scene, got {type(scene).__name__}")
    shape = scene.config_shape
    if not (shape == () or (len(shape) == 2 and shape[0] in (1, b) and shape[1] == 1)):
        raise SceneError(
            f"refine: the scene has configurations of shape {tuple(shape)}; a photo is one view: "
            f"give a scene of shape () or ({b}, 1)"
        )
    return scene


def _light_xy(scene: Scene, batch: int) -> Tensor:
    """``(B, 2)``: the point of the patch under the (first) light of a one-view scene."""
    light = scene.lights[0]
    pos = light.resolve(scene.camera).position if isinstance(light, Flash) else light.position
    return pos.reshape(-1, 3)[:, :2].expand(batch, 2)


def dielectric_prior(prior: SVBRDF, below: float) -> SVBRDF:
    """``prior`` with the specular of each material whose mean specular luminance is below
    ``below`` set to the grey :data:`~svbrdf_render.metalrough.DIELECTRIC_F0` of most dielectrics."""
    if below <= 0:
        return prior
    spec = prior.specular
    lum = (spec.mean((2, 3)) * spec.new_tensor([0.2126, 0.7152, 0.0722])).sum(1)
    grey = (lum < below).to(spec.dtype)[:, None, None, None]
    specular = spec * (1 - grey) + DIELECTRIC_F0 * grey
    return SVBRDF(prior.normal, prior.diffuse, prior.roughness, specular, validate=False)


# -- the prior term (see the module), which refine_views adds to its data term too --------------


def prior_targets(prior: SVBRDF) -> dict[str, Tensor]:
    """The prior's maps on their stored encodings, computed once per refinement."""
    return {name: stored_value(name, t) for name, t in prior.maps().items()}


def prior_weights(settings: RefineSettings) -> dict[str, float]:
    """Each map's prior weight of ``settings`` (0 for a map it does not name)."""
    return {name: float(settings.prior.get(name, 0.0)) for name in MAP_NAMES}


def with_prior(loss: Tensor, maps: SVBRDF, targets: dict[str, Tensor], weights: dict[str, float]) -> Tensor:
    """``loss + sum_map w_map * mean |x - x_prior|`` (maps of zero weight left out)."""
    for name, t in maps.maps().items():
        if weights[name] > 0:
            loss = loss + weights[name] * (stored_value(name, t) - targets[name]).abs().mean()
    return loss


class RefineLoss:
    """The objective of :func:`refine_maps` for one photo batch: ``loss(maps) -> scalar``.

    ``data + sum_map w_map * prior_map`` (see the module docstring), averaged over the batch.
    Built once per refinement: the photo's log and the prior's stored encodings are computed
    here, not at every step.
    """

    def __init__(
        self,
        photo: Tensor,
        prior: SVBRDF,
        scene: Scene,
        settings: RefineSettings,
        backend: str,
        highlight: Tensor | None = None,
        exclude: Tensor | None = None,
    ):
        self.scene = scene
        self.eps = settings.eps
        self.backend = backend
        self.target = log_radiance(photo.clamp(0, 1), settings.eps)
        self.prior = prior_targets(prior)
        self.weights = prior_weights(settings)
        self.ring_weight = float(settings.rings)
        point = _light_xy(scene, photo.shape[0]) if highlight is None else highlight
        self.bins = RingBins(point.to(photo.device), photo.shape, photo.device, exclude)  # held: not the material

    def data(self, maps: SVBRDF) -> Tensor:
        """``mean |log(clip(render) + eps) - log(photo + eps)|``."""
        rendering = _view(render(maps, self.scene, backend=self.backend)).clamp(0, 1)
        return (log_radiance(rendering, self.eps) - self.target).abs().mean()

    def rings(self, maps: SVBRDF) -> Tensor:
        """How much the maps depend on the distance to the point under the flash
        (:func:`svbrdf_render.refinement.rings.ring_penalty`)."""
        return ring_penalty(maps, self.bins)

    def __call__(self, maps: SVBRDF) -> Tensor:
        loss = self.data(maps)
        if self.ring_weight > 0:
            loss = loss + self.ring_weight * self.rings(maps)
        return with_prior(loss, maps, self.prior, self.weights)


def _check_point(point: Any, photo: Tensor) -> Tensor | None:
    """``highlight`` of :func:`refine_maps` as ``(B, 2)`` on the photo's device, or an error."""
    if point is None:
        return None
    b = photo.shape[0]
    if not isinstance(point, Tensor) or point.shape not in ((2,), (1, 2), (b, 2)):
        shape = tuple(point.shape) if isinstance(point, Tensor) else type(point).__name__
        raise MapError(f"refine: highlight must be a tensor (2,), (1, 2) or ({b}, 2), got {shape}")
    if not bool(torch.isfinite(point).all()):
        raise MapError("refine: highlight holds a non-finite coordinate")
    return point.reshape(-1, 2).to(photo.device, torch.float32).expand(b, 2)


def _check_budget(steps: Any, seconds: Any, backend: Any) -> None:
    """The step count, time bound and backend of :func:`refine_maps`, or a ``ValueError``."""
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"refine: steps must be an integer >= 0, got {steps!r}")
    if seconds is not None and not (seconds >= 0 and math.isfinite(seconds)):
        raise ValueError(f"refine: seconds must be a finite number >= 0, got {seconds!r}")
    if backend not in BACKENDS:
        raise ValueError(f"refine: backend must be one of {BACKENDS}, got {backend!r}")


def _check_held(held: Any, photo: Tensor, size: tuple[int, int], device) -> tuple[Tensor, SVBRDF] | None:
    """``held`` of :func:`refine_maps` as ``(mask (B, 1, H, W) bool, maps at the photo's size)``."""
    if held is None:
        return None
    mask, maps = held
    b = photo.shape[0]
    if not isinstance(mask, Tensor) or mask.dim() != 4 or mask.shape[1] != 1 or mask.shape[0] not in (1, b):
        shape = tuple(mask.shape) if isinstance(mask, Tensor) else type(mask).__name__
        raise MapError(f"refine: held's mask must be (B, 1, H, W) or (1, 1, H, W), got {shape}")
    if tuple(mask.shape[-2:]) != size:
        raise MapError(f"refine: held's mask is {tuple(mask.shape[-2:])}, the photo {size}")
    if not isinstance(maps, SVBRDF) or maps.batch_size not in (1, b):
        raise MapError("refine: held's maps must be an SVBRDF of 1 or B materials")
    return mask.to(device, torch.bool), refine_start(maps.detach().to(device, torch.float32), size)


def _with_held(maps: SVBRDF, held: tuple[Tensor, SVBRDF] | None) -> SVBRDF:
    """``maps`` with ``held``'s maps where its mask is true."""
    if held is None:
        return maps
    mask, fixed = held
    return SVBRDF(
        *(torch.where(mask, getattr(fixed, n).expand_as(t), t) for n, t in maps.maps().items()), validate=False
    )


def _optimise(
    params: _Parameters,
    loss_fn: RefineLoss,
    settings: RefineSettings,
    steps: int,
    seconds: float | None,
    callback: Callable[[int, int, float], None] | None,
    t0: float,
    held: tuple[Tensor, SVBRDF] | None = None,
) -> list[float]:
    """Adam on ``params`` for ``steps`` steps, or until ``seconds`` after ``t0``; the losses."""
    from .fit import _Adam

    opt = _Adam(params.groups(settings.lr, settings.normal_lr_scale))  # torch.optim.Adam's steps, 0.8 s sooner
    losses = []
    for step in range(steps):
        opt.zero_grad()
        loss = loss_fn(_with_held(params.svbrdf(), held))
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if callback is not None:
            callback(step + 1, steps, losses[-1])
        if seconds is not None and time.perf_counter() - t0 >= seconds:
            break
    return losses


def refine_maps(
    photo: Tensor,
    start: SVBRDF,
    *,
    scene: Scene | None = None,
    flash: str = "axis",
    prior: SVBRDF | None = None,
    steps: int = 200,
    seconds: float | None = None,
    settings: RefineSettings | None = None,
    backend: str = "compiled",
    callback: Callable[[int, int, float], None] | None = None,
    highlight: Tensor | None = None,
    held: tuple[Tensor, SVBRDF] | None = None,
) -> Refinement:
    """Optimise maps so that their rendering under ``scene`` matches ``photo``.

    Args:
        photo: ``(B, 3, H, W)`` (or ``(3, H, W)``) linear photos in [0, 1] (values outside are
            clipped; a saturated pixel only asks the rendering to be at least as bright).
        start: maps of B materials to start from, any size (resized to ``H x W``).
        scene: the capture: camera, flash and Des18 effects, shape ``()`` or ``(B, 1)``.
        flash: with no scene, how to find the flash from ``start``: ``"axis"`` (default: the
            Des18 capture on the axis at distance 2.2, intensity from a median) or
            ``"fit"`` (position too, by :func:`fit_flash`).
        prior: maps the prior term pulls toward (default: ``start``), resized likewise.
        steps: at most this many Adam steps (0 returns the start, resized).
        seconds: stop once this much wall time has passed (``None``: no time bound).
        settings: weights and step sizes (:class:`RefineSettings`).
        backend: the renderer's backend, ``"compiled"`` (default) or ``"eager"``.
        callback: ``callback(step, total, loss)`` after each step (``total`` is ``steps``).
        highlight: ``(B, 2)`` patch coordinates of the point under the flash, the centre of
            the ring penalty (:func:`svbrdf_render.refinement.rings.highlight_point` reads it off a
            photo); default: under the scene's light.
        held: ``(mask (B, 1, H, W), maps)``: maps held where ``mask`` is true (a reference card).

    Returns:
        A :class:`Refinement`. A ``KeyboardInterrupt`` from the callback or the user
        propagates: nothing is returned half-done.
    """
    t0 = time.perf_counter()
    settings = settings or RefineSettings()
    _check_budget(steps, seconds, backend)
    photo = _check(photo, start, prior)
    size = tuple(photo.shape[-2:])
    photo = photo.to(start.device)
    start = refine_start(start.detach().to(torch.float32), size)
    prior = start if prior is None else refine_start(prior.detach().to(torch.float32), size)
    prior = dielectric_prior(prior, settings.dielectric)
    scene = _scene_for(photo, start, scene, flash)
    held = _check_held(held, photo, size, start.device)
    if steps == 0 or seconds == 0:
        return Refinement(_with_held(start, held), scene, 0, time.perf_counter() - t0, torch.zeros(0))
    params = _Parameters(start, settings.coarse, settings.hold)
    exclude = None if held is None else held[0]  # a held card is no part of the material's rings
    loss_fn = RefineLoss(photo, prior, scene, settings, backend, _check_point(highlight, photo), exclude)
    losses = _optimise(params, loss_fn, settings, steps, seconds, callback, t0, held)
    with torch.no_grad():
        out = _with_held(params.svbrdf(), held).detach()
    return Refinement(out, scene, len(losses), time.perf_counter() - t0, torch.tensor(losses))
