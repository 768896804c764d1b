"""Comparing two map sets, or a rendering with a photo: the one place the project's per-sample
accuracy figures are defined (training's validation, the benchmark, refinement's photo fit,
the metal/rough round trip).

Every figure is an RMSE per sample, so callers can average, or bootstrap over samples:

- maps: on the values a map file stores, all in [0, 1]: normal as ``(n + 1) / 2``, diffuse
  and specular linear, roughness as is (so the four RMSEs share one scale);
- renderings: under :func:`svbrdf_render.evaluation_scene` (6 fixed light/view pairs, the
  same for every model), each rendering clipped to [0, 1] and sRGB-encoded as a display would
  show it, which is how images are compared in the Des18 literature.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .formats.mapfiles import linear_to_srgb
from .maps import MAP_NAMES, SVBRDF, stored_value
from .renderer import render
from .sampling import evaluation_scene
from .scene import Scene

__all__ = ["METRIC_NAMES", "display_rendering", "map_rmse", "per_sample_rmse", "render_rmse"]

#: Names of :func:`map_rmse`'s figures and then :func:`render_rmse`'s.
METRIC_NAMES = (*MAP_NAMES, "render")


def per_sample_rmse(a: Tensor, b: Tensor) -> Tensor:
    """``(B,)`` RMSE over everything but the first dimension of two equal-shaped batches."""
    return (a.float() - b.float()).square().flatten(1).mean(1).sqrt()


def _stored(svbrdf: SVBRDF) -> dict[str, Tensor]:
    m = svbrdf.maps()
    return {name: stored_value(name, m[name]) for name in MAP_NAMES}


def map_rmse(pred: SVBRDF, target: SVBRDF) -> dict[str, Tensor]:
    """``{map name: (B,) RMSE}`` between the stored encodings of two map sets."""
    if pred.shape != target.shape:
        raise ValueError(
            f"map_rmse: pred is {pred.shape}, target {target.shape}; expected the same (B, H, W)"
        )
    p, t = _stored(pred), _stored(target)
    return {name: per_sample_rmse(p[name], t[name]) for name in MAP_NAMES}


def display_rendering(svbrdf: SVBRDF, scene: Scene) -> Tensor:
    """Renderings as a screen shows them: clipped to [0, 1], sRGB-encoded."""
    return linear_to_srgb(render(svbrdf, scene).clamp(0, 1))


def render_rmse(pred: SVBRDF, target: SVBRDF, scene: Scene | None = None) -> Tensor:
    """``(B,)`` RMSE of display renderings under ``scene`` (default: the 6 evaluation pairs)."""
    if pred.shape != target.shape:
        raise ValueError(
            f"render_rmse: pred is {pred.shape}, target {target.shape}; expected the same (B, H, W)"
        )
    scene = scene if scene is not None else evaluation_scene(device=pred.device)
    with torch.no_grad():
        a = display_rendering(pred, scene)
        b = display_rendering(target, scene)
    return per_sample_rmse(a, b)
