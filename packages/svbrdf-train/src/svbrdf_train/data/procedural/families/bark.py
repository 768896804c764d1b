"""The bark family of procedural materials.

Plates between deep furrows along the trunk (darker, rougher), cracks across the plates,
weathered tops, lichen.
"""

from typing import Any

from torch import Tensor

from ..noise import Draw, fbm, mix, smoothstep
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    p = draw_frame(d, aligned=0.6)  # v along the trunk: furrows run along v
    p["across"] = d.uniform(2.0, 7.0)  # furrows per patch unit, about
    p["along"] = p["across"] * d.uniform(0.05, 0.15)  # long plates
    p["warp"], p["warp_freq"] = d.uniform(0.05, 0.3), d.uniform(0.5, 1.5)
    p["level"] = d.uniform(-0.25, 0.15)  # where plates end and furrows begin
    p["edge"] = d.uniform(0.08, 0.3)
    p["depth"] = d.uniform(0.25, 0.7)  # slope of the plates' flanks
    p["cracks"], p["crack_freq"] = d.uniform(0.0, 1.0), d.uniform(3.0, 8.0)
    p["fibre_relief"] = d.uniform(0.02, 0.08)
    base = (
        d.colour((0.03, 0.1), (0.2, 0.6), (0.12, 0.45))
        if d.chance(0.7)
        else d.colour((0.0, 1.0), (0.0, 0.12), (0.2, 0.55))
    )
    p["base"] = base
    p["weathered"] = vary(d, base, (1.0, 1.6), (0.2, 0.6))  # grey, sun-bleached plate tops
    p["weather"] = d.uniform(0.0, 0.7)
    p["furrow_colour"] = vary(d, base, (0.25, 0.6), (1.0, 1.3))
    p["lichen"] = d.uniform(0.3, 1.0) if d.chance(0.3) else 0.0
    p["lichen_colour"] = d.colour((0.12, 0.3), (0.15, 0.5), (0.4, 0.75))
    p["lichen_level"] = d.uniform(0.0, 0.4)
    p["roughness"] = d.uniform(0.6, 0.8)
    p["furrow_roughness"] = d.uniform(0.84, 0.95)
    p["specular"] = grey(d.uniform(0.025, 0.04))
    p["lattice"] = d.lattice(5)  # warp, plates, cracks, fibres, lichen
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    fw = p["warp_freq"]
    w = fbm(p["lattice"][:, 0:1], u * fw, v * fw, 2)
    fa, fl = p["across"], p["along"]
    n = fbm(p["lattice"][:, 1:2], (u + p["warp"] * w) * fa, v * fl, 4, turn=False)
    plate = smoothstep(p["level"] - p["edge"], p["level"] + p["edge"], n)
    furrow = 1 - plate
    # Cracks across the plates: thin lines of noise stretched across the trunk.
    fc = p["crack_freq"]
    c = fbm(p["lattice"][:, 2:3], u * fc * 0.4, v * fc, 2, turn=False)
    crack = (1 - c.abs() * 8).clamp(0, 1) * plate * p["cracks"]
    fib = fbm(p["lattice"][:, 3:5], u * fa * 10, v * fl * 3, 2, turn=False)
    fibre, blotch = fib[:, 0:1], fib[:, 1:2]
    lichen = smoothstep(p["lichen_level"], p["lichen_level"] + 0.2, blotch) * plate * p["lichen"]

    top = plate * (1 + 0.15 * n)  # the plates' tops are not flat
    height = p["depth"] * p["edge"] / fa * (top - 0.6) - 0.3 * p["depth"] / fc * crack
    height = height + p["fibre_relief"] / (fa * 10) * fibre + 0.004 * lichen
    face = mix(p["base"], p["weathered"], plate * p["weather"] * smoothstep(-0.5, 0.8, n))
    diffuse = mix(p["furrow_colour"], face * (1 + 0.1 * fibre), plate)
    diffuse = mix(diffuse * (1 - 0.5 * crack), p["lichen_colour"] * (1 + 0.1 * fibre), lichen)
    roughness = mix(p["furrow_roughness"], p["roughness"] + 0.04 * fibre, plate)
    roughness = mix(roughness, p["furrow_roughness"], crack)
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"furrow": furrow})


# weight: the least: the narrowest look
register(Family("bark", "bark: plates between deep furrows, cracks, lichen", draw, fields,
                order=90, weight=0.4))
