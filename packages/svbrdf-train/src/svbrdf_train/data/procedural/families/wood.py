"""The wood family of procedural materials.

Rings, fibres, pores; optionally planks with seams.
"""

from typing import Any

import torch
from torch import Tensor

from ..noise import Draw, fbm, fract, lookup, mix, smoothstep, wrap
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    p = draw_frame(d, aligned=0.5)
    # Boards are placed by their own shifts below; a shift here could cross a board edge.
    p["shift_u"] = p["shift_v"] = 0.0
    p["rings"] = d.uniform(2.0, 9.0)  # rings per patch unit
    p["pith"] = d.uniform(-1.5, 1.5)
    p["tilt"] = d.uniform(-0.15, 0.15)
    p["warp"], p["warp_along"], p["warp_across"] = (
        d.uniform(0.01, 0.1),
        d.uniform(0.3, 1.2),
        d.uniform(1.0, 3.0),
    )
    p["fibre_along"], p["fibre_across"] = d.uniform(0.5, 2.0), d.uniform(40.0, 90.0)
    p["fibre"], p["pores"] = d.uniform(0.1, 0.4), d.uniform(0.0, 1.0)
    if d.chance(0.6):  # planks: width, length and seams
        p["plank_width"], p["plank_length"] = d.uniform(0.3, 0.9), d.uniform(0.8, 3.0)
        p["seam"] = d.uniform(0.002, 0.008)
        p["plank_shift"], p["end_base"], p["end_jitter"] = d.uniform(0.0, p["plank_width"]), 0.0, 1.0
    else:  # one board much larger than the patch, centred on it: no edge can show
        p["plank_width"], p["plank_length"], p["seam"] = 16.0, 64.0, 0.0
        p["plank_shift"], p["end_base"], p["end_jitter"] = 8.0, 0.5, 0.0
    tone = d.choice(["natural", "dark", "weathered"], [0.65, 0.25, 0.1])
    if tone == "natural":
        early = d.colour((0.04, 0.11), (0.3, 0.65), (0.5, 0.9))
    elif tone == "dark":
        early = d.colour((0.02, 0.09), (0.4, 0.8), (0.18, 0.42))
    else:
        early = d.colour((0.05, 0.15), (0.02, 0.12), (0.35, 0.7))
    p["early"], p["late"] = early, vary(d, early, (0.45, 0.8), (1.0, 1.3))
    p["late_weight"] = d.uniform(0.5, 1.0)
    if d.chance(0.5):  # varnished
        p["roughness"], p["specular"] = d.uniform(0.12, 0.35), grey(d.uniform(0.04, 0.06))
        p["relief"], p["fibre_relief"] = d.uniform(0.0, 0.01), d.uniform(0.005, 0.02)
    else:
        p["roughness"], p["specular"] = d.uniform(0.45, 0.75), grey(d.uniform(0.03, 0.045))
        p["relief"], p["fibre_relief"] = d.uniform(0.01, 0.04), d.uniform(0.02, 0.08)
    p["board_value"] = d.table(256, -1.0, 1.0)
    p["board_centre"] = d.table(256, -1.0, 1.0)
    p["board_depth"] = d.table(256, 0.1, 2.5)
    p["board_phase"] = d.table(256)
    p["row_shift"] = d.table(256)
    p["board_jitter"] = d.uniform(0.0, 0.15)
    p["lattice"] = d.lattice(3)  # warp, fibres, pores
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    a, b = frame(p, x, y)  # a along the grain
    pw, pl = p["plank_width"], p["plank_length"]
    bb = b + p["plank_shift"]
    j = torch.floor(bb / pw)
    across = bb - (j + 0.5) * pw  # across the board, from its middle
    aa = a + (p["end_base"] + p["end_jitter"] * lookup(p["row_shift"], wrap(j, 256).long())) * pl
    k = torch.floor(aa / pl)
    along = aa - k * pl
    board = (wrap(j, 16) * 16 + wrap(k, 16)).long()
    # Seams between boards: distance to the nearest board edge, patch units.
    edge = torch.minimum(0.5 * pw - across.abs(), torch.minimum(along, pl - along))
    seam = (1 - smoothstep(p["seam"], p["seam"] + 0.004, edge)) * (p["seam"] > 0)

    warp = fbm(p["lattice"][:, 0:1], a * p["warp_along"], b * p["warp_across"], 3, turn=False)
    centre = p["pith"] + 0.5 * pw.clamp(max=1.0) * lookup(p["board_centre"], board)
    depth = lookup(p["board_depth"], board)
    c = across - centre
    r = torch.sqrt(c * c + depth * depth) + p["tilt"] * a + p["warp"] * warp
    q = fract(r * p["rings"] + lookup(p["board_phase"], board))
    q2 = q * q
    late = q2 * q2 * p["late_weight"]  # latewood darkens towards the end of each ring
    fib = fbm(p["lattice"][:, 1:3], a * p["fibre_along"], b * p["fibre_across"], 2, turn=False)
    fibre = fib[:, 0:1]
    pores = smoothstep(0.45, 0.8, fib[:, 1:2]) * p["pores"]

    t = (late + p["fibre"] * fibre).clamp(0, 1)
    early = p["early"] * (1 + p["board_jitter"] * lookup(p["board_value"], board))
    diffuse = mix(early, p["late"], t) * (1 - 0.35 * pores)
    diffuse = diffuse * (1 - 0.6 * seam)
    rings = p["relief"] / p["rings"]
    fibres = p["fibre_relief"] / p["fibre_across"]
    height = rings * late + fibres * (fibre - 0.5 * pores) - 0.01 * seam
    roughness = p["roughness"] * (1 + 0.1 * late + 0.2 * pores)
    roughness = mix(roughness, 0.8, seam)
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"seam": seam})


# weight: a surface Des18 lacks
register(Family("wood", "rings, fibres and pores, optionally planks with seams", draw, fields,
                order=40, weight=0.6))
