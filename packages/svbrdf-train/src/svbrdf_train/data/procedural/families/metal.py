"""The metal family of procedural materials.

Brushed, polished and scratched, hammered, sandblasted, embossed; coloured specular (measured
F0, or tarnished and anodised: darker), dark diffuse.
"""

from typing import Any

import torch
from torch import Tensor

from ..noise import Draw, fbm, fract, sample_lattice, smoothstep, worley
from .base import Family, Fields, register
from .drawing import draw_frame, draw_metal_specular, frame, grey


def draw(d: Draw) -> dict[str, Any]:
    p = draw_frame(d)
    p["specular"], tint = draw_metal_specular(d)
    dark = d.uniform(0.0, 0.04)
    p["diffuse"] = tuple(dark * c for c in tint) if d.chance(0.5) else grey(dark)
    finish = d.choice(
        ["brushed", "polished", "hammered", "sandblasted", "embossed"], [0.3, 0.15, 0.2, 0.15, 0.2]
    )
    p["brushed"] = 1.0 if finish == "brushed" else 0.0
    p["hammered"] = 1.0 if finish == "hammered" else 0.0
    p["sandblasted"] = 1.0 if finish == "sandblasted" else 0.0
    p["embossed"] = 1.0 if finish == "embossed" else 0.0
    p["scratches"] = 1.0 if finish == "polished" else d.uniform(0.0, 0.6)
    p["roughness"] = {
        "brushed": d.uniform(0.15, 0.4),
        "polished": d.uniform(0.08, 0.25),
        "hammered": d.uniform(0.1, 0.35),
        "sandblasted": d.uniform(0.35, 0.55),
        "embossed": d.uniform(0.15, 0.45),
    }[finish]
    p["streak_along"], p["streak_across"] = d.uniform(1.0, 4.0), d.uniform(40.0, 120.0)
    p["streak_roughness"], p["streak_relief"] = d.uniform(0.03, 0.12), d.uniform(0.02, 0.08)
    for s in range(3):  # scratch directions
        p[f"scratch_cos{s}"], p[f"scratch_sin{s}"] = d.angle()
    p["scratch_along"], p["scratch_across"] = d.uniform(0.3, 1.5), d.uniform(15.0, 45.0)
    p["scratch_density"] = d.uniform(0.1, 0.6)
    p["dent_freq"], p["dent_relief"] = d.uniform(2.0, 5.0), d.uniform(0.05, 0.2)
    p["sand_freq"], p["sand_relief"] = d.uniform(25.0, 60.0), d.uniform(0.03, 0.1)
    # Embossed (tread plate, studded sheet): round bumps on a square or staggered grid;
    # their steepest slope is 1.54 relief / radius, here 0.3-1.2.
    p["emboss_freq"], p["emboss_radius"] = d.uniform(4.0, 12.0), d.uniform(0.12, 0.32)
    p["emboss_relief"] = d.uniform(0.3, 1.2) * p["emboss_radius"] / 1.54
    p["emboss_stagger"] = 0.5 if d.chance(0.4) else 0.0
    p["smudge"] = d.uniform(0.0, 1.0)
    p["smudge_freq"] = d.uniform(1.0, 3.0)
    p["points"] = d.cells(d.uniform(0.0, 0.5))
    p["lattice"] = d.lattice(5)  # streaks, scratches, scratch presence, sand, smudges
    return p


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)  # u along the brushing
    streak = fbm(p["lattice"][:, 0:1], u * p["streak_along"], v * p["streak_across"], 3, turn=False)

    # Scratches: thin ridges of stretched noise along three directions, kept where a
    # coarse noise says so.
    us, vs = [], []
    for s in range(3):
        cs, sn = p[f"scratch_cos{s}"], p[f"scratch_sin{s}"]
        us.append(u * cs - v * sn)
        vs.append(u * sn + v * cs)
    su, sv = torch.cat(us, dim=1), torch.cat(vs, dim=1)
    lines = sample_lattice(p["lattice"][:, 1:2], su * p["scratch_along"], sv * p["scratch_across"])[:, :, 0]
    where = sample_lattice(p["lattice"][:, 2:3], su * 0.7, sv * 0.7)[:, :, 0]
    ridge = (1 - lines.abs() * 6).clamp(0, 1)
    ridge = ridge * ridge * smoothstep(1 - p["scratch_density"], 1.2 - p["scratch_density"], where)
    scratch = torch.maximum(torch.maximum(ridge[:, 0:1], ridge[:, 1:2]), ridge[:, 2:3]) * p["scratches"]

    f1, _, _ = worley(p["points"], u * p["dent_freq"], v * p["dent_freq"])
    dent = (1 - f1).clamp(0, 1)
    dent = dent * dent
    sand = fbm(p["lattice"][:, 3:4], u * p["sand_freq"], v * p["sand_freq"], 2)
    smudge = fbm(p["lattice"][:, 4:5], u * p["smudge_freq"], v * p["smudge_freq"], 3)
    dirt = smoothstep(0.0, 0.8, smudge) * p["smudge"]
    fe, radius = p["emboss_freq"], p["emboss_radius"]
    ev = v * fe
    eu = u * fe + p["emboss_stagger"] * torch.floor(ev)
    cu, cv = fract(eu) - 0.5, fract(ev) - 0.5
    boss = (1 - (cu * cu + cv * cv) / (radius * radius)).clamp(0, 1)
    boss = boss * boss  # (1 - r^2 / R^2)^2: round, flat-footed bumps

    height = (
        p["brushed"] * (p["streak_relief"] / p["streak_across"]) * streak
        - 0.3 / p["scratch_across"] * scratch
        - p["hammered"] * (p["dent_relief"] / p["dent_freq"]) * (dent - 0.3)
        + p["sandblasted"] * (p["sand_relief"] / p["sand_freq"]) * sand
        + p["embossed"] * (p["emboss_relief"] / fe) * (boss - 0.2)
    )
    roughness = (
        p["roughness"]
        + p["brushed"] * p["streak_roughness"] * streak
        + 0.15 * scratch
        + p["sandblasted"] * 0.08 * sand
        + 0.2 * dirt
    )
    specular = p["specular"] * (1 - 0.05 * dirt)
    diffuse = p["diffuse"] + 0.03 * dirt
    return Fields(height, diffuse.expand_as(specular), roughness, specular, {"scratch": scratch})


# weight: a Des18 family, a little more than the others (often dark, often coloured)
register(Family("metal", "brushed, polished and scratched, hammered, sandblasted, embossed", draw, fields,
                order=50, weight=1.2))
