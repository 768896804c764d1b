"""The plaster family of procedural materials.

Plaster, stucco, concrete: broad low bumps, stucco dabs, pores and air holes (recessed,
rougher); near-grey, rough.
"""

from typing import Any

from torch import Tensor

from ..noise import CELL_PERIOD, Draw, fbm, lookup, mix, smoothstep, worley
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    kind = d.choice(["plaster", "stucco", "concrete"], [0.35, 0.3, 0.35])
    p = draw_frame(d)
    p["freq"] = d.log_uniform(0.6, 2.0)  # broad bumps of the wall, cells per patch unit
    p["gain"] = d.uniform(0.45, 0.6)
    p["relief"] = d.uniform(0.01, 0.04)  # slope of the broad bumps: walls are nearly flat
    # Stucco: thrown or trowelled dabs of plaster standing on the wall, flat-topped.
    p["stucco"] = 1.0 if kind == "stucco" else 0.0
    p["dab_freq"] = d.uniform(4.0, 12.0)
    p["dab_level"], p["dab_soft"] = d.uniform(-0.1, 0.3), d.uniform(0.05, 0.25)
    p["dab_relief"] = d.uniform(0.1, 0.35)
    p["grain_freq"] = d.uniform(30.0, 70.0)
    p["grain_relief"] = d.uniform(0.01, 0.04) if kind != "plaster" else d.uniform(0.003, 0.015)
    # Pores and air holes: small round pits, most in concrete.
    p["pore_freq"] = d.uniform(10.0, 30.0)
    p["pore_density"] = d.uniform(0.2, 0.6) if kind == "concrete" else d.uniform(0.0, 0.2)
    p["pore_radius"] = d.uniform(0.1, 0.3)  # in cells
    p["pore_depth"] = d.uniform(0.15, 0.4)  # the pit walls' slope over 2.5
    if kind == "concrete":
        base = d.colour((0.0, 1.0), (0.0, 0.08), (0.35, 0.75))
    else:  # near-grey whites and earthy tints of render and paint
        base = (
            d.colour((0.05, 0.15), (0.0, 0.25), (0.45, 0.95))
            if d.chance(0.6)
            else d.colour((0.0, 1.0), (0.05, 0.4), (0.3, 0.85))
        )
    p["base"] = base
    p["stain_colour"] = vary(d, base, (0.4, 0.8), (0.8, 1.5))  # damp, dirt, weathering
    p["stain"] = d.uniform(0.0, 0.7)
    p["mottle"] = d.uniform(0.02, 0.12)
    p["roughness"] = d.uniform(0.6, 0.82)
    p["roughness_var"] = d.uniform(0.02, 0.08)
    p["specular"] = grey(d.uniform(0.025, 0.04))
    p["points"] = d.cells(d.uniform(0.0, 0.4))
    p["pore_table"] = d.table(CELL_PERIOD * CELL_PERIOD)
    p["lattice"] = d.lattice(4)  # bumps, stains, dabs, grain
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    f = p["freq"]
    n = fbm(p["lattice"][:, 0:2], u * f, v * f, 5, p["gain"])
    bumps, stain = n[:, 0:1], n[:, 1:2]
    fs, fg = p["dab_freq"], p["grain_freq"]
    dabs = fbm(p["lattice"][:, 2:3], u * fs, v * fs, 3)
    grain = fbm(p["lattice"][:, 3:4], u * fg, v * fg, 2)
    dab = smoothstep(p["dab_level"], p["dab_level"] + p["dab_soft"], dabs) * p["stucco"]
    fp = p["pore_freq"]
    f1, _, cell = worley(p["points"], u * fp, v * fp)
    r = p["pore_radius"]
    present = (lookup(p["pore_table"], cell) < p["pore_density"]).float()
    pore = (1 - smoothstep(0.6 * r, r, f1)) * present
    height = (
        p["relief"] / f * bumps
        + p["dab_relief"] * p["dab_soft"] / fs * dab
        + p["grain_relief"] / fg * grain
        - p["pore_depth"] * r / fp * pore
    )
    wet = smoothstep(0.0, 0.8, stain) * p["stain"]
    diffuse = mix(p["base"], p["stain_colour"], wet) * (1 + p["mottle"] * grain) * (1 - 0.35 * pore)
    face = (p["roughness"] + p["roughness_var"] * grain - 0.04 * dab).clamp(max=0.86)
    roughness = mix(face, 0.93, pore)  # pores and holes stay rougher
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"pore": pore})


# weight: a surface Des18 lacks, common: rough near-grey, low relief
register(Family("plaster", "plaster, stucco and concrete: broad bumps, dabs, pores", draw, fields,
                order=70, weight=0.6))
