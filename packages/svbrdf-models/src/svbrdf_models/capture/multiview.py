"""What the captures of one material in several views share (``predict --calibrated DIR``,
:mod:`~svbrdf_models.capture.calibrated`, and ``predict --shots``,
:mod:`~svbrdf_models.capture.shots`): the network's maps refined against every view under its
own scene (:func:`refine_network`), both map sets re-rendered under each view and judged
against its photo (:func:`judge`), rerender.png's rows (:func:`views_figure`) and the relit
preview (:func:`relit_preview`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from svbrdf_render import SVBRDF, RefineSettings, Scene, linear_to_srgb, refine_start, refine_views

from .figures import HEAT_MAX, error_heatmap, image_grid
from .refining import (
    as_dielectric,
    pick_backend,
    rerender,
    rerender_rmse,
    steps_seconds,
    without_checkerboard,
)

__all__ = ["Judged", "finite", "flatter", "judge", "refine_network", "relit_preview", "views_figure"]


def finite(x) -> float | None:
    """``x`` rounded to 6 digits for material.json, None when it is not finite."""
    return round(float(x), 6) if math.isfinite(float(x)) else None


@dataclass(frozen=True)
class Judged:
    """Each view's clipped re-renderings by the network's and the refined maps, and RMSEs."""

    network: Tensor  # (N, 3, S, S)
    refined: Tensor
    rmse_network: list[float]
    rmse: list[float]


def judge(photos: Tensor, scenes: list[Scene], network: SVBRDF, refined: SVBRDF) -> Judged:
    """Both map sets re-rendered under every view's own scene (``scenes[i]`` for ``photos[i]``),
    against its photo (linear, clipped: the same encoding for both)."""
    size = tuple(photos.shape[-2:])
    net = torch.cat([rerender(network, s, size) for s in scenes])
    ref = torch.cat([rerender(refined, s, size) for s in scenes])
    return Judged(net, ref, rerender_rmse(net, photos).tolist(), rerender_rmse(ref, photos).tolist())


def views_figure(photos: Tensor, judged: Judged, labels: list[str]) -> Tensor:
    """rerender.png: a row per view: photo | network's | refined re-rendering | refined error;
    each row's label (``labels[i]``, e.g. the file and its role) followed by both RMSEs."""
    rows, texts = [], []
    for i, label in enumerate(labels):
        shown = [linear_to_srgb(x[i]) for x in (photos, judged.network, judged.refined)]
        rows.append([*shown, error_heatmap(photos[i], judged.refined[i])])
        texts.append(f"{label}: RMSE {judged.rmse_network[i]:.4f} -> {judged.rmse[i]:.4f}")
    columns = ["photo", "network's maps", "refined maps", f"refined |error| 0-{HEAT_MAX:g}"]
    return image_grid(rows, columns, texts, min_tile=160)


def relit_preview(network: SVBRDF, refined: SVBRDF, options) -> Tensor | None:
    """relit.gif's frames of the refined maps, relit.png's grid of both, or None (``options.relit``)."""
    from .relight import relit_grid, relit_versions

    if options.relit == "none":
        return None
    frames = relit_versions([network, refined])
    return relit_grid(frames, ["network", "refined"]) if options.relit == "png" else frames[-1]


def refine_network(network: SVBRDF, photos: Tensor, scenes: list[Scene], options, progress, device, *,
                   masks: Tensor | None = None, gains: str = "fixed", anchor: list[int] | None = None,
                   began: float | None = None, settings: RefineSettings | None = None,
                   prior_relief: float = 1.0):  # fmt: skip
    """The network's maps (without their 2-pixel pattern, at the photos' size) refined against
    ``photos`` ``(K, 3, S, S)``, each under its own scene, on ``device``
    (:func:`svbrdf_render.refine_views`; ``options.refine`` steps, 0: none). ``options.metal``
    ``"none"``: the specular held at a dielectric's 0.04 (:func:`.refining.as_dielectric`).
    ``began`` (``time.monotonic()`` when the capture began): ``options.refine_seconds`` counts
    from there and keeps back the files' time (:func:`.refining.steps_seconds`). ``settings``: the
    refinement's weights (default :class:`svbrdf_render.RefineSettings`'s). ``prior_relief``: the
    share of the network's relief the normals are pulled towards (:func:`flatter`; 1: the
    network's normals, 0: a flat surface; they start at the network's whatever it is)."""
    size = tuple(photos.shape[-2:])
    seconds = options.refine_seconds
    if began is not None:
        seconds = steps_seconds(seconds, began, size[0] * size[1], True)
    dielectric = getattr(options, "metal", "auto") == "none"
    with torch.inference_mode(False), torch.enable_grad():
        maps = SVBRDF(**{k: t.detach().clone() for k, t in network.maps().items()}, validate=False)
        start = refine_start(without_checkerboard(maps), size).to(device)
        start = as_dielectric(start) if dielectric else start
        result = refine_views(
            photos.to(device),
            start,
            scenes,
            prior=None if prior_relief == 1.0 else flatter(start, prior_relief),
            masks=None if masks is None else masks.to(device),
            gains=gains,
            anchor=anchor,
            steps=options.refine,
            seconds=seconds,
            backend=pick_backend(options.backend, *size),
            callback=progress,
            settings=_held_dielectric(settings) if dielectric else settings,
        )
    return dataclasses.replace(result, svbrdf=as_dielectric(result.svbrdf)) if dielectric else result


def flatter(maps: SVBRDF, relief: float) -> SVBRDF:
    """``maps`` with each normal's slope (its x and y over z) times ``relief``: 0 a flat
    surface, 1 the maps' own."""
    n = maps.normal
    slope = n[:, :2] / n[:, 2:].clamp_min(1e-3) * relief
    normal = torch.cat([slope, torch.ones_like(n[:, 2:])], 1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    return SVBRDF(normal, maps.diffuse, maps.roughness, maps.specular, validate=False)


def _held_dielectric(settings: RefineSettings | None) -> RefineSettings:
    """``settings`` with the specular held at the start's (``--metal none``)."""
    return dataclasses.replace(settings or RefineSettings(), hold=("specular",))
