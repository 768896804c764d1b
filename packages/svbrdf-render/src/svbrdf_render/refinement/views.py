"""Refine one material against several photos of it, each under its own camera and light.

One flash photo cannot separate a bright diffuse from a highlight, nor relief from albedo;
photos with the light in different places can. :func:`refine_views` moves the maps of ONE
material through the differentiable renderer until their renderings under K known views
match the K photos::

    from svbrdf_render import refine_views
    result = refine_views(photos, start, scenes, steps=200)   # photos (K, 3, H, W)
    result.svbrdf, result.residuals                            # maps, RMSE of each view

The views are a :class:`~svbrdf_render.Scene` of configuration shape ``(1, K)`` (one camera and
light per view) or a list of K one-view scenes; a list is stacked into one ``(1, K)`` scene when
the scenes share their effects, light colours, field of view and kinds of light, so that the K
renderings are one call of the renderer (else each view is rendered by itself).

The loss is :func:`svbrdf_render.refine_maps`' own, over every seen pixel of every view
(``R_k`` the rendering of view k times its gain ``g_k``, clipped to [0, 1]; ``m_k`` its mask)::

    data  = sum_k sum_px m_k |log(R_k + eps) - log(P_k + eps)| / (3 sum_k sum_px m_k)
    prior = sum_map w_map * mean | x - x_prior |        (refinement/refine.py, refine_maps' term)

with the same parametrisation of the maps (:class:`~svbrdf_render.refinement.refine.RefineSettings`,
the dielectric prior included). Without masks the data term is the plain mean, so that one view
gives :func:`~svbrdf_render.refine_maps`' loss exactly (with its rings off).

The ring penalty is left off. It is a one-flash notion: it penalises maps whose means change
with the distance to the one point under the flash, because a single photo cannot tell the
highlight from the maps. With several views the highlights fall on different points, and a
highlight baked into the maps at one view's point is contradicted by the others' photos: the
data term does the penalty's work, and a penalty centred on each view's point in turn would
pull against a material that truly varies there.

Gains: ``"fixed"`` renders each view as its scene says (the light's power is known);
``"free"`` learns a log exposure gain per view (a camera's exposure that was not recorded),
with the views of ``anchor`` (default: view 0) held at gain 1: a gain common to all views
trades exactly with the albedos, so one view must fix the level. Anchor every view to say
that a reference fixed them all (the same as ``"fixed"``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import MapError, SceneError
from ..maps import SVBRDF
from ..renderer import log_radiance, render
from ..scene import Camera, PointLight, Scene
from .refine import (RefineSettings, _check_budget, _optimise, _Parameters, dielectric_prior, prior_targets,
                     prior_weights, refine_start, with_prior)

__all__ = ["GAIN_MODES", "ViewsRefinement", "refine_views", "stack_views"]

#: What ``gains`` of :func:`refine_views` takes.
GAIN_MODES = ("fixed", "free")


@dataclass(frozen=True)
class ViewsRefinement:
    """What :func:`refine_views` returns.

    Attributes:
        svbrdf: the refined maps of the one material, at the photos' size (detached).
        scenes: the views: one scene of shape ``(1, K)``, or the list of K scenes given when
            they could not be stacked.
        gains: ``(K,)`` each view's gain (a factor on its rendering; 1 where fixed).
        residuals: ``(K,)`` RMSE of each view's clipped re-rendering (gain applied) against its
            photo over its mask (mask-weighted); NaN for a view whose mask sees nothing.
        steps: Adam steps taken.
        seconds: wall time of the refinement.
        losses: ``(steps,)`` the loss before each step.
    """

    svbrdf: SVBRDF
    scenes: Scene | list[Scene]
    gains: Tensor
    residuals: Tensor
    steps: int
    seconds: float
    losses: Tensor


def _one_view(scene: Scene, i: int) -> Scene:
    if not isinstance(scene, Scene):
        raise SceneError(f"refine_views: scenes[{i}] is a {type(scene).__name__}, not a Scene")
    if tuple(scene.config_shape) not in ((), (1,), (1, 1)):
        raise SceneError(
            f"refine_views: scenes[{i}] has configurations of shape {tuple(scene.config_shape)}; "
            "each scene of a list is one view: shape () or (1, 1)"
        )
    return scene


def stack_views(scenes: Sequence[Scene]) -> Scene | None:
    """K one-view scenes as one scene of configuration shape ``(1, K)``, or None when they
    differ in what a configuration dimension cannot carry (effects, the number or colours of
    the lights, the camera's field of view, a directional camera or light)."""
    scenes = [_one_view(s, i) for i, s in enumerate(scenes)]
    first = scenes[0]
    lights = [s.point_lights for s in scenes]
    same = all(
        s.effects == first.effects
        and float(s.camera.fov) == float(first.camera.fov)
        and s.camera.directional is False
        and len(ls) == len(lights[0])
        and all(lt.directional is False and torch.equal(lt.color, l0.color) for lt, l0 in zip(ls, lights[0]))
        for s, ls in zip(scenes, lights)
    )
    if not same:
        return None
    cam = torch.stack([s.camera.position.reshape(3) for s in scenes])[None]
    stacked = []
    for j, l0 in enumerate(lights[0]):
        pos = torch.stack([ls[j].position.reshape(3) for ls in lights])[None]
        power = torch.stack([ls[j].intensity.reshape(()) for ls in lights])[None]
        stacked.append(PointLight(pos, power, l0.color))
    return Scene(Camera(cam, first.camera.fov), tuple(stacked), first.effects)


class _Views:
    """The K views: ``render(maps) -> (K, 3, H, W)``, in one call when they stack."""

    def __init__(self, scenes: Scene | Sequence[Scene], device):
        if isinstance(scenes, Scene):
            shape = tuple(scenes.config_shape)
            if shape == ():
                scenes = [scenes]
            elif not (len(shape) == 2 and shape[0] == 1 or len(shape) == 1):
                raise SceneError(
                    f"refine_views: the scene has configurations of shape {shape}; one material "
                    "seen in K views is a scene of shape (1, K) (or a list of K one-view scenes)"
                )
        elif not isinstance(scenes, (list, tuple)) or not scenes:
            raise SceneError("refine_views: expected a Scene of shape (1, K) or a list of K one-view scenes")
        if isinstance(scenes, Scene):
            self.scene: Scene | None = scenes.to(device)
            self.given: Scene | list[Scene] = scenes
            self.count = int(scenes.config_shape[-1])
        else:
            stacked = stack_views(scenes)
            self.scene = None if stacked is None else stacked.to(device)
            self.given = list(scenes) if stacked is None else stacked
            self.each = [s.to(device) for s in scenes]
            self.count = len(scenes)

    def render(self, maps: SVBRDF, backend: str) -> Tensor:
        if self.scene is not None:
            return render(maps, self.scene, backend=backend)[0]
        out = [render(maps, s, backend=backend) for s in self.each]
        return torch.cat([r.reshape(-1, *r.shape[-3:]) for r in out])


def _check_inputs(photos: Tensor, start: SVBRDF, prior: SVBRDF | None, masks: Tensor | None, k: int):
    """The photos ``(K, 3, H, W)`` clamped to [0, 1] and the masks ``(K, 1, H, W)`` (or None)."""
    if not isinstance(photos, Tensor) or photos.dim() != 4 or photos.shape[1] != 3:
        shape = tuple(photos.shape) if isinstance(photos, Tensor) else type(photos).__name__
        raise MapError(f"refine_views: expected photos (K, 3, H, W), got {shape}")
    if photos.shape[0] != k:
        raise MapError(f"refine_views: {photos.shape[0]} photo(s) but {k} view(s)")
    if not bool(torch.isfinite(photos).all()):
        raise MapError("refine_views: the photos hold NaN or infinite values")
    for what, maps in (("start", start), ("prior", prior)):
        if maps is not None and (not isinstance(maps, SVBRDF) or maps.batch_size != 1):
            raise MapError(f"refine_views: {what} must be the maps of ONE material (an SVBRDF of batch 1)")
    if masks is not None:
        want = (k, 1, *photos.shape[-2:])
        if not isinstance(masks, Tensor) or tuple(masks.shape) != want:
            shape = tuple(masks.shape) if isinstance(masks, Tensor) else type(masks).__name__
            raise MapError(f"refine_views: masks must be {want}, weights of each view's pixels; got {shape}")
        masks = masks.to(torch.float32)
        if not bool(torch.isfinite(masks).all()) or bool((masks < 0).any()):
            raise MapError("refine_views: masks must be finite weights >= 0 (0: a pixel not seen)")
    return photos.float().clamp(0, 1), masks


def _free_views(gains: str, anchor: Sequence[int] | None, k: int) -> Tensor:
    """``(K,)`` 1 where the view's gain is learnt, 0 where it is held at 1."""
    if gains not in GAIN_MODES:
        raise ValueError(f"refine_views: gains must be one of {GAIN_MODES}, got {gains!r}")
    free = torch.zeros(k) if gains == "fixed" else torch.ones(k)
    for i in (0,) if anchor is None else anchor:
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < k:
            raise ValueError(f"refine_views: anchor names view {i!r}; views are 0 to {k - 1}")
        free[i] = 0.0
    return free


class _ViewsLoss:
    """``data + prior`` of the module docstring for one material seen in K views."""

    def __init__(self, photos, masks, prior, views: _Views, settings: RefineSettings, backend: str,
                 log_gain: Tensor, free: Tensor):  # fmt: skip
        self.views, self.backend, self.eps = views, backend, settings.eps
        self.target = log_radiance(photos, settings.eps)
        self.masks = masks
        self.prior, self.weights = prior_targets(prior), prior_weights(settings)
        self.log_gain = log_gain
        self.free = free

    def renderings(self, maps: SVBRDF, backend: str | None = None) -> Tensor:
        """``(K, 3, H, W)``: each view's rendering times its gain, clipped to [0, 1]."""
        rendering = self.views.render(maps, backend or self.backend)
        if bool(self.free.any()):
            rendering = rendering * torch.exp(self.log_gain * self.free)[:, None, None, None]
        return rendering.clamp(0, 1)

    def __call__(self, maps: SVBRDF) -> Tensor:
        error = (log_radiance(self.renderings(maps), self.eps) - self.target).abs()
        if self.masks is None:
            data = error.mean()
        else:
            data = (error * self.masks).sum() / (3 * self.masks.sum()).clamp_min(1e-12)
        return with_prior(data, maps, self.prior, self.weights)


class _WithGains:
    """The map parameters and the views' log gains, as :func:`refine._optimise` steps them."""

    def __init__(self, params: _Parameters, log_gain: Tensor, free: Tensor):
        self.params, self.log_gain, self.free = params, log_gain, free

    def groups(self, lr: float, normal_scale: float) -> list[dict]:
        extra = [{"params": [self.log_gain], "lr": lr}] if bool(self.free.any()) else []
        return self.params.groups(lr, normal_scale) + extra

    def svbrdf(self) -> SVBRDF:
        return self.params.svbrdf()


def _residuals(renderings: Tensor, photos: Tensor, masks: Tensor | None) -> Tensor:
    """``(K,)`` mask-weighted RMSE of each view; NaN where the mask sees nothing."""
    sq = (renderings - photos).square()
    if masks is None:
        return sq.flatten(1).mean(1).sqrt()
    seen = 3 * masks.flatten(1).sum(1)
    rmse = ((sq * masks).flatten(1).sum(1) / seen.clamp_min(1e-12)).sqrt()
    return torch.where(seen > 0, rmse, torch.full_like(rmse, float("nan")))


def refine_views(
    photos: Tensor,
    start: SVBRDF,
    scenes: Scene | Sequence[Scene],
    *,
    prior: SVBRDF | None = None,
    masks: Tensor | None = None,
    gains: str = "fixed",
    anchor: Sequence[int] | None = None,
    steps: int = 200,
    seconds: float | None = None,
    settings: RefineSettings | None = None,
    backend: str = "compiled",
    callback: Callable[[int, int, float], None] | None = None,
) -> ViewsRefinement:
    """Optimise the maps of one material so that its renderings match K photos of it.

    Args:
        photos: ``(K, 3, H, W)`` linear photos in [0, 1] (values outside are clipped), each the
            patch ``[-1, 1]^2`` rectified to the same pixels.
        start: the maps of ONE material to start from, any size (resized to ``H x W``).
        scenes: a scene of configuration shape ``(1, K)`` (one camera and light per view), or
            a list of K one-view scenes (stacked when they can be: :func:`stack_views`).
        prior: maps the prior term pulls toward (default: ``start``).
        masks: ``(K, 1, H, W)`` weights of each view's pixels (0: not seen); default all 1.
        gains: ``"fixed"`` (default) or ``"free"``: a log gain per view is learnt, but for
            the views of ``anchor`` (default: view 0), held at 1.
        anchor: with ``gains="free"``, the views whose gain is held at 1.
        steps, seconds, settings, backend, callback: as :func:`svbrdf_render.refine_maps`
            (``settings.rings`` is not used: see the module docstring).

    Returns:
        A :class:`ViewsRefinement` (the gains and residuals on the CPU).
    """
    t0 = time.perf_counter()
    settings = settings or RefineSettings()
    _check_budget(steps, seconds, backend)
    views = _Views(scenes, start.device if isinstance(start, SVBRDF) else None)
    photos, masks = _check_inputs(photos, start, prior, masks, views.count)
    free = _free_views(gains, anchor, views.count).to(start.device)
    size = tuple(photos.shape[-2:])
    photos = photos.to(start.device)
    masks = None if masks is None else masks.to(start.device)
    start = refine_start(start.detach().to(torch.float32), size)
    prior = start if prior is None else refine_start(prior.detach().to(torch.float32), size)
    log_gain = torch.zeros(views.count, device=start.device, requires_grad=True)
    loss_fn = _ViewsLoss(photos, masks, dielectric_prior(prior, settings.dielectric), views, settings,
                         backend, log_gain, free)  # fmt: skip
    params = _Parameters(start, settings.coarse, settings.hold)
    losses: list[float] = []
    if steps and seconds != 0:
        stepped = _WithGains(params, log_gain, free)
        losses = _optimise(stepped, loss_fn, settings, steps, seconds, callback, t0)
    with torch.no_grad():
        out = params.svbrdf().detach() if losses else start
        final = loss_fn.renderings(out, "eager")  # one render: not worth a compile
        residuals = _residuals(final, photos, masks).cpu()
        gain = torch.exp(log_gain * free).detach().cpu()
    return ViewsRefinement(out, views.given, gain, residuals, len(losses), time.perf_counter() - t0,
                           torch.tensor(losses))  # fmt: skip
