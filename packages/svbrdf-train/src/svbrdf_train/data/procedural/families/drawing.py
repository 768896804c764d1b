"""Drawing helpers shared by the procedural families: pattern frames, colour variations, metals.

The draws are made from a material's own :class:`~svbrdf_train.data.procedural.noise.Draw`, in
Python floats; :func:`frame` is the one batched op here (the pattern coordinates).
"""

from __future__ import annotations

import math

from torch import Tensor

from ...stats import LUMINANCE
from ..noise import Draw

__all__ = ["COLOURED_METALS", "METALS", "draw_frame", "draw_metal_specular", "frame", "grey", "vary"]


def grey(value: float) -> tuple[float, float, float]:
    """An RGB triple of one value: a colourless albedo."""
    return (value, value, value)


def draw_frame(d: Draw, aligned: float = 0.0) -> dict[str, float]:
    """A rotation and a shift of the pattern. With probability ``aligned`` the rotation is a
    quarter turn plus a few degrees (tiles and planks are usually shot square)."""
    if d.chance(aligned):
        a = d.integer(0, 3) * math.pi / 2 + math.radians(d.uniform(-4.0, 4.0))
        cs, sn = math.cos(a), math.sin(a)
    else:
        cs, sn = d.angle()
    return {"cos": cs, "sin": sn, "shift_u": d.uniform(0.0, 64.0), "shift_v": d.uniform(0.0, 64.0)}


def frame(p: dict[str, Tensor], x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Pattern coordinates ``(B, 1, H, W)``: the pixel positions rotated, then shifted."""
    u = x * p["cos"] - y * p["sin"] + p["shift_u"]
    v = x * p["sin"] + y * p["cos"] + p["shift_v"]
    return u, v


def vary(d: Draw, rgb, value: tuple[float, float], saturation: tuple[float, float] = (1.0, 1.0)):
    """A second colour near ``rgb``: brightness scaled by ``value``, chroma by ``saturation``."""
    k, s = d.uniform(*value), d.uniform(*saturation)
    mean = sum(rgb) / 3
    return tuple(min(max(k * (mean + s * (c - mean)), 0.0), 1.0) for c in rgb)


#: Linear specular albedo (F0) of real metals at normal incidence (from measured indices of
#: refraction, as tabulated for physically based shading); those with a mean of at least 0.55,
#: so that a drawn metal keeps a mean specular albedo of at least 0.5.
METALS = {
    "gold": (1.0, 0.766, 0.336),
    "silver": (0.972, 0.960, 0.915),
    "aluminium": (0.913, 0.922, 0.924),
    "copper": (0.955, 0.638, 0.538),
    "iron": (0.562, 0.565, 0.578),
    "chromium": (0.550, 0.556, 0.554),
    "brass": (0.910, 0.778, 0.423),
    "nickel": (0.660, 0.609, 0.526),
    "zinc": (0.664, 0.824, 0.850),
    "platinum": (0.673, 0.637, 0.585),
    "cobalt": (0.662, 0.655, 0.634),
}


#: Metals whose specular albedo is clearly coloured; drawn twice as often as the others.
COLOURED_METALS = ("gold", "copper", "brass")


def draw_metal_specular(d: Draw) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The specular albedo of one metal and its hue (for a tinted diffuse).

    *Bright* (25%): a measured F0 of :data:`METALS`. *Dark* (45%): the same colour at a
    luminance of 0.09-0.3, as tarnished, oxidised or darkened metal appears in captured and
    authored materials (Des18's metals are mostly such). *Anodised* (30%): a dyed colour at
    that luminance.
    """
    names = sorted(METALS)
    f0 = METALS[d.choice(names, [2.0 if n in COLOURED_METALS else 1.0 for n in names])]
    tone = d.choice(["bright", "dark", "anodised"], [0.25, 0.45, 0.3])
    if tone == "bright":
        k = d.uniform(0.96, 1.0)
        return tuple(k * c for c in f0), f0
    colour = f0 if tone == "dark" else d.colour((0.0, 1.0), (0.2, 0.6), (0.6, 1.0))
    level = d.log_uniform(0.09, 0.3)
    lum = sum(w * c for w, c in zip(LUMINANCE, colour, strict=True))
    return tuple(min(c * level / lum, 1.0) for c in colour), colour
