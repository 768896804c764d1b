"""The cells family of procedural materials.

Leather, cobbles, cracked earth and paint: Worley cells with gaps between them.
"""

from typing import Any

from torch import Tensor

from ..noise import CELL_PERIOD, Draw, fbm, lookup, mix, smoothstep, worley
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    kind = d.choice(["leather", "cobbles", "cracked"], [0.4, 0.3, 0.3])
    p = draw_frame(d)
    if kind == "leather":
        p["freq"] = d.uniform(6.0, 14.0)
        regularity, p["gap"], p["round"] = d.uniform(0.0, 0.3), d.uniform(0.04, 0.12), d.uniform(0.1, 0.3)
        p["dome"], p["slope"] = d.uniform(0.0, 0.3), d.uniform(0.1, 0.3)
        tone = d.choice(["brown", "black", "tan", "dyed"], [0.4, 0.2, 0.2, 0.2])
        c = {
            "brown": ((0.03, 0.09), (0.45, 0.8), (0.12, 0.45)),
            "black": ((0.0, 1.0), (0.0, 0.2), (0.03, 0.12)),
            "tan": ((0.06, 0.1), (0.35, 0.6), (0.5, 0.75)),
            "dyed": ((0.0, 1.0), (0.4, 0.8), (0.15, 0.5)),
        }[tone]
        base = d.colour(*c)
        p["base"], p["second"] = base, vary(d, base, (0.85, 1.1))
        p["gap_colour"] = vary(d, base, (0.45, 0.8), (1.0, 1.2))
        p["cell_jitter"], p["multi"] = d.uniform(0.02, 0.08), 0.3
        p["roughness"], p["gap_roughness"] = d.uniform(0.3, 0.6), d.uniform(0.65, 0.8)
        p["specular"] = grey(d.uniform(0.035, 0.06))
        p["grain"] = d.uniform(0.03, 0.1)
    elif kind == "cobbles":
        p["freq"] = d.uniform(1.2, 3.0)
        regularity, p["gap"], p["round"] = d.uniform(0.0, 0.5), d.uniform(0.06, 0.2), d.uniform(0.15, 0.3)
        p["dome"], p["slope"] = d.uniform(0.15, 0.45), d.uniform(0.15, 0.35)
        base = d.colour((0.0, 0.13), (0.0, 0.35), (0.25, 0.7))
        p["base"], p["second"] = base, d.colour((0.0, 0.13), (0.0, 0.35), (0.2, 0.75))
        p["gap_colour"] = d.colour((0.07, 0.12), (0.1, 0.4), (0.2, 0.6))
        p["cell_jitter"], p["multi"] = d.uniform(0.15, 0.4), 1.0
        p["roughness"], p["gap_roughness"] = d.uniform(0.4, 0.7), d.uniform(0.75, 0.92)
        p["specular"] = grey(d.uniform(0.03, 0.05))
        p["grain"] = d.uniform(0.05, 0.15)
    else:  # cracked earth or paint
        p["freq"] = d.uniform(1.5, 4.0)
        regularity, p["gap"], p["round"] = d.uniform(0.0, 0.3), d.uniform(0.015, 0.04), d.uniform(0.02, 0.08)
        p["dome"], p["slope"] = d.uniform(0.0, 0.1), d.uniform(0.3, 0.8)
        if d.chance(0.5):  # dried earth
            base = d.colour((0.05, 0.12), (0.2, 0.55), (0.3, 0.7))
            p["roughness"], p["specular"] = d.uniform(0.55, 0.75), grey(d.uniform(0.025, 0.04))
        else:  # cracked paint
            base = d.colour((0.0, 1.0), (0.05, 0.7), (0.4, 0.95))
            p["roughness"], p["specular"] = d.uniform(0.3, 0.6), grey(d.uniform(0.035, 0.05))
        p["base"], p["second"] = base, vary(d, base, (0.85, 1.1))
        p["gap_colour"] = vary(d, base, (0.15, 0.4))
        p["cell_jitter"], p["multi"] = d.uniform(0.02, 0.1), 0.2
        p["gap_roughness"] = d.uniform(0.75, 0.92)
        p["grain"] = d.uniform(0.03, 0.1)
    p["grain_freq"] = p["freq"] * d.uniform(4.0, 8.0)
    p["points"] = d.cells(regularity)
    p["cell_values"] = d.table(2 * CELL_PERIOD * CELL_PERIOD, -1.0, 1.0).view(2, -1)
    p["lattice"] = d.lattice(2)  # grain, mottling
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    k = p["freq"]
    f1, f2, cell = worley(p["points"], u * k, v * k)
    edge = f2 - f1  # about twice the distance to the cell border, in cells
    inside = smoothstep(p["gap"], p["gap"] + p["round"], edge)
    gap = 1 - smoothstep(0.5 * p["gap"], p["gap"], edge)
    values = lookup(p["cell_values"], cell)
    fg = p["grain_freq"]
    n = fbm(p["lattice"], u * fg, v * fg, 3)
    grain, mottle = n[:, 0:1], n[:, 1:2]

    dome = (1 - f1 * f1).clamp(0, 1)  # a paraboloid around the cell's point
    height = p["slope"] / k * (p["round"] * (inside - 0.8) + p["dome"] * (dome * inside - 0.5))
    height = height + p["grain"] / fg * grain
    cell_colour = mix(p["base"], p["second"], (0.5 + 0.5 * values[:, 1:2]) * p["multi"])
    cell_colour = cell_colour * (1 + p["cell_jitter"] * values[:, 0:1]) * (1 + 0.08 * mottle)
    diffuse = mix(cell_colour, p["gap_colour"], gap)
    roughness = mix(p["roughness"] * (1 + 0.1 * grain), p["gap_roughness"], gap)
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"gap": gap})


# weight: a family of the Des18 materials: they keep the bulk of the draws
register(Family("cells", "leather, cobbles, cracked earth and paint (Worley cells)", draw, fields,
                order=30, weight=1.0))
