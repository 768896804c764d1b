"""Per-sample accuracy figures of predicted maps: what validation logs and the benchmark reports.
They are defined once, in :mod:`svbrdf_render.compare` (the renderer's package, so the photo
tool and the metal/rough round trip use the same ones); this module names them for training,
with the preview flash of its sample grids.

What each figure measures (stored encodings, display renderings under the 6 evaluation
views) is said there.
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
