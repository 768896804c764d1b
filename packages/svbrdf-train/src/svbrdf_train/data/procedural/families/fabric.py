"""The fabric family of procedural materials.

Plain, twill and satin weaves of round threads; stripes and checks.
"""

from typing import Any

import torch
from torch import Tensor

from ..noise import Draw, fbm, lookup, wrap
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    p = draw_frame(d, aligned=0.5)
    weave = d.choice(["plain", "twill 2/2", "twill 2/1", "satin"], [0.4, 0.25, 0.15, 0.2])
    # Warp thread i is over weft thread j when (i * step + j) mod repeat < over.
    p["repeat"], p["step"], p["over"] = {
        "plain": (2.0, 1.0, 1.0),
        "twill 2/2": (4.0, 1.0, 2.0),
        "twill 2/1": (3.0, 1.0, 2.0),
        "satin": (5.0, 2.0, d.choice([1.0, 4.0])),
    }[weave]
    p["threads"] = d.uniform(10.0, 40.0)  # per patch unit
    p["width"] = d.uniform(0.7, 0.95)  # of the thread spacing
    p["thickness"], p["lift"] = d.uniform(0.15, 0.35), d.uniform(0.05, 0.15)
    warp = d.colour((0.0, 1.0), (0.05, 0.8), (0.1, 0.9))
    if d.chance(0.5):  # one yarn both ways
        weft = warp
    elif d.chance(0.5):  # a lighter or darker shade
        weft = vary(d, warp, (0.6, 1.3))
    else:  # another colour (denim: blue warp, white weft)
        weft = d.colour((0.0, 1.0), (0.0, 0.6), (0.2, 0.95))
    # Yarn-dyed patterns (stripes, checks): a colour per thread from a short repeat.
    period = d.integer(2, 12) if d.chance(0.3) else 1
    accent = d.colour((0.0, 1.0), (0.1, 0.8), (0.1, 0.9))
    warp_tab, weft_tab = torch.empty(3, 16), torch.empty(3, 16)
    for t in range(16):
        stripe = period > 1 and (t % period) < max(1, period // 3)
        warp_tab[:, t] = torch.tensor(accent if stripe else warp)
        weft_tab[:, t] = torch.tensor(accent if stripe and d.chance(0.8) else weft)
    p["period"] = float(period)
    p["warp_colours"], p["weft_colours"] = warp_tab, weft_tab
    satin = weave == "satin"
    p["roughness"] = d.uniform(0.3, 0.55) if satin else d.uniform(0.5, 0.8)
    p["specular"] = grey(d.uniform(0.035, 0.055) if satin else d.uniform(0.025, 0.045))
    p["fuzz"] = d.uniform(0.0, 0.3)
    p["lattice"] = d.lattice(3)  # warp fibres, weft fibres, fuzz
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    k = p["threads"]
    a, b = u * k, v * k  # warp threads run along v, weft threads along u
    i, j = torch.floor(a), torch.floor(b)
    fa, fb = a - i, b - j
    over = (wrap(i * p["step"] + j, p["repeat"]) < p["over"]).float()  # warp on top here
    sign = 2 * over - 1

    def profile(t: Tensor) -> Tensor:  # round thread cross-section, 0 at its edges
        s = ((t - 0.5) / (0.5 * p["width"])).clamp(-1, 1)
        return torch.sqrt(1 - s * s)

    cross_w, cross_f = profile(fa), profile(fb)
    # The thread on top arches up in the middle of the crossing, the other one dips.
    warp_h = p["thickness"] * cross_w + p["lift"] * sign * 4 * fb * (1 - fb)
    weft_h = p["thickness"] * cross_f - p["lift"] * sign * 4 * fa * (1 - fa)
    on_warp = warp_h >= weft_h
    # Fibres run along their thread: noise stretched along v for the warp, along u for the weft.
    warp_fibre = fbm(p["lattice"][:, 0:1], a * 6, b * 0.6, 2, turn=False)
    weft_fibre = fbm(p["lattice"][:, 1:2], a * 0.6, b * 6, 2, turn=False)
    fuzz = fbm(p["lattice"][:, 2:3], a * 3, b * 3, 2)

    warp_c = lookup(p["warp_colours"], wrap(i, p["period"]).long()) * (1 + 0.12 * warp_fibre)
    weft_c = lookup(p["weft_colours"], wrap(j, p["period"]).long()) * (1 + 0.12 * weft_fibre)
    fibre = torch.where(on_warp, warp_fibre, weft_fibre)
    thread = torch.maximum(cross_w, cross_f)  # 0 in the holes between threads
    diffuse = torch.where(on_warp, warp_c, weft_c) * (0.45 + 0.55 * thread)
    top = torch.maximum(warp_h, weft_h) - 0.7 * p["thickness"]
    height = (top + 0.04 * fibre + 0.05 * p["fuzz"] * fuzz) / k
    roughness = p["roughness"] + 0.05 * fibre + 0.1 * p["fuzz"] * (0.5 + 0.5 * fuzz)
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"warp": on_warp.float()})


# weight: a surface Des18 lacks
register(Family("fabric", "plain, twill and satin weaves, stripes and checks", draw, fields,
                order=60, weight=0.5))
