"""Per-sample accuracy figures of predicted maps: what validation logs and the benchmark reports.
They are defined once, in :mod:`svbrdf_render.compare` (the renderer's package, so the photo
tool and the metal/rough round trip use the same ones); this module names them for training,
with the preview flash of its sample grids.

Every figure is an RMSE per sample, so callers can average, or bootstrap over samples:

- maps: on the values a map file stores, all in [0, 1]: normal as ``(n + 1) / 2``, diffuse
  and specular linear, roughness as is (so the four RMSEs share one scale);
- renderings: under :func:`svbrdf_render.evaluation_scene` (6 fixed light/view pairs, the
  same for every model), each rendering clipped to [0, 1] and sRGB-encoded as a display would
  show it, which is how images are compared in the Des18 literature.
"""

from __future__ import annotations

import math

from svbrdf_render import DES18_DISTANCE, Scene
from svbrdf_render.compare import METRIC_NAMES, display_rendering, map_rmse, per_sample_rmse, render_rmse

__all__ = ["map_rmse", "render_rmse", "display_rendering", "per_sample_rmse", "preview_flash", "METRIC_NAMES"]


def preview_flash(device=None) -> Scene:
    """The Des18 phone flash, bright enough that an albedo of 1 at the centre shows as 1:
    what sample grids re-render maps under for people to look at."""
    return Scene.flash(intensity=math.pi * DES18_DISTANCE**2).to(device)
