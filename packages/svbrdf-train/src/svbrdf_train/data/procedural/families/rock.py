"""The rock family of procedural materials.

Rough rock with strong warped low-frequency relief and folds, crevices (darker, rougher), lichen
and moss patches.
"""

from typing import Any

from torch import Tensor

from ..noise import Draw, fbm, mix, smoothstep, worley
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    p = draw_frame(d)
    p["freq"] = d.log_uniform(0.5, 1.6)
    p["warp"], p["gain"] = d.uniform(0.3, 1.2), d.uniform(0.5, 0.62)
    p["relief"] = d.uniform(0.04, 0.1)  # slope of the broad relief (per octave: steeper in sum)
    p["ridge"] = d.uniform(0.0, 1.0)  # sharp ridges and folds rather than round bumps
    p["crack_freq"] = d.uniform(1.5, 5.0)
    p["crack_width"] = d.uniform(0.03, 0.1)  # in cells
    p["cracks"] = 1.0 if d.chance(0.7) else 0.0
    p["crack_depth"] = d.uniform(0.06, 0.15)  # the crevice walls' slope over 4
    p["grain_freq"] = d.uniform(20.0, 50.0)
    p["grain_relief"] = d.uniform(0.02, 0.06)
    tone = d.choice(["grey", "brown", "dark"], [0.4, 0.35, 0.25])
    base = {
        "grey": d.colour((0.0, 1.0), (0.0, 0.12), (0.2, 0.6)),
        "brown": d.colour((0.04, 0.12), (0.2, 0.55), (0.2, 0.6)),
        "dark": d.colour((0.0, 1.0), (0.0, 0.3), (0.06, 0.2)),
    }[tone]
    p["base"], p["second"] = base, vary(d, base, (0.6, 1.3), (0.7, 1.5))
    p["crevice_colour"] = vary(d, base, (0.2, 0.5))
    p["lichen"] = d.uniform(0.4, 1.0) if d.chance(0.35) else 0.0
    lichen = d.choice(  # moss green, orange-yellow, pale grey
        [
            ((0.12, 0.3), (0.2, 0.6), (0.3, 0.7)),
            ((0.07, 0.14), (0.5, 0.9), (0.5, 0.85)),
            ((0.0, 1.0), (0.0, 0.1), (0.6, 0.85)),
        ]
    )
    p["lichen_colour"] = d.colour(*lichen)
    p["lichen_level"], p["lichen_freq"] = d.uniform(0.0, 0.5), d.uniform(2.0, 6.0)
    p["roughness"], p["roughness_var"] = d.uniform(0.55, 0.78), d.uniform(0.03, 0.1)
    p["crevice_roughness"] = d.uniform(0.86, 0.95)
    p["specular"] = grey(d.uniform(0.028, 0.045))
    p["points"] = d.cells(d.uniform(0.0, 0.3))
    p["lattice"] = d.lattice(5)  # warp u, warp v, relief, colour, grain
    p["lichen_lattice"] = d.lattice(1)
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    f = p["freq"]
    uf, vf = u * f, v * f
    w = fbm(p["lattice"][:, 0:2], uf, vf, 3)
    uw, vw = uf + p["warp"] * w[:, 0:1], vf + p["warp"] * w[:, 1:2]
    n = fbm(p["lattice"][:, 2:4], uw, vw, 5, p["gain"])
    relief, tone = n[:, 0:1], n[:, 1:2]
    shape = relief + p["ridge"] * (0.4 - relief.abs())  # folds: ridges where the noise crosses 0
    k = p["crack_freq"] / f
    f1, f2, _ = worley(p["points"], uw * k, vw * k)
    cw = p["crack_width"]
    crevice = (1 - smoothstep(0.5 * cw, cw, f2 - f1)) * p["cracks"]
    fg = p["grain_freq"]
    grain = fbm(p["lattice"][:, 4:5], u * fg, v * fg, 2)
    fl = p["lichen_freq"]
    patch = fbm(p["lichen_lattice"], u * fl, v * fl, 4)
    lichen = smoothstep(p["lichen_level"], p["lichen_level"] + 0.15, patch + 0.2 * grain) * p["lichen"]
    lichen = lichen * (1 - crevice)

    height = p["relief"] / f * shape - p["crack_depth"] * cw / p["crack_freq"] * crevice
    height = height + p["grain_relief"] / fg * grain + 0.003 * lichen
    stone = mix(p["base"], p["second"], smoothstep(-0.6, 0.6, tone)) * (1 + 0.1 * grain)
    stone = stone * (1 + 0.25 * (shape - 0.2))  # dirt collects low, ridges are lighter
    diffuse = mix(mix(stone, p["crevice_colour"], crevice), p["lichen_colour"] * (1 + 0.15 * grain), lichen)
    face = (p["roughness"] + p["roughness_var"] * grain).clamp(max=0.84)
    roughness = mix(mix(face, p["crevice_roughness"], crevice), 0.85 + 0.05 * grain, lichen)
    parts = {"crevice": crevice, "lichen": lichen}
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), parts)


# order: last; weight: a surface Des18 lacks, common: rough near-grey, strong relief
register(Family("rock", "rough rock: strong warped relief, crevices, lichen and moss", draw, fields,
                order=100, weight=0.6))
