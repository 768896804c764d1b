"""The preview flash of training's sample grids, beside the accuracy figures they show.

The per-sample accuracy figures of predicted maps (what validation logs and the benchmark
reports: map and render RMSE, display renderings under the 6 evaluation views) are defined
once, in :mod:`svbrdf_render.compare` (the renderer's package, so the photo tool and the
metal/rough round trip use the same ones): import them from there.
"""

from __future__ import annotations

import math

from svbrdf_render import DES18_DISTANCE, Scene

__all__ = ["preview_flash"]


def preview_flash(device=None) -> Scene:
    """The Des18 phone flash, bright enough that an albedo of 1 at the centre shows as 1:
    what sample grids re-render maps under for people to look at."""
    return Scene.flash(intensity=math.pi * DES18_DISTANCE**2).to(device)
