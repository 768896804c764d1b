"""The tiles family of procedural materials.

Tiles, bricks, mosaics; grout recessed, rougher, another colour; some with metal studs where the
tiles meet.
"""

from typing import Any

import torch
from torch import Tensor

from ..noise import Draw, fbm, lookup, mix, smoothstep, wrap
from .base import Family, Fields, register
from .drawing import draw_frame, draw_metal_specular, frame, grey


def draw(d: Draw) -> dict[str, Any]:
    layout = d.choice(["grid", "bricks", "stack", "mosaic", "random bond"], [0.3, 0.3, 0.1, 0.15, 0.15])
    p = draw_frame(d, aligned=0.75)
    rows, aspect, bond, row_jitter = _draw_layout(d, layout)
    p["rows"], p["columns"], p["bond"], p["row_jitter"] = rows, rows / aspect, bond, row_jitter
    brick = layout in ("bricks", "random bond")
    style = "brick" if brick else d.choice(["glazed", "terracotta", "stone"], [0.5, 0.25, 0.25])
    colour, jitter, mottle, rough, spec, relief, grout = _draw_style(d, style)
    size = 1.0 / rows  # tile height, patch units
    p["grout_width"] = size * (d.uniform(0.05, 0.12) if brick else d.uniform(0.015, 0.07))
    p["bevel"] = size * d.uniform(0.02, 0.12)
    p["depth"] = p["bevel"] * d.uniform(0.4, 1.2)  # bevel slope 0.4-1.2
    p["tilt"] = d.uniform(0.0, 0.04)
    p["colour"], p["grout_colour"] = colour, grout
    p["jitter"], p["mottle"], p["relief"] = jitter, mottle, relief
    p["roughness"], p["grout_roughness"] = rough, d.uniform(0.72, 0.9)
    p["specular"], p["grout_specular"] = grey(spec), grey(d.uniform(0.025, 0.04))
    p["noise_freq"] = rows * d.uniform(2.0, 6.0)
    _draw_studs(d, p, layout, size)
    p["lattice"] = d.lattice(3)  # mottling, bumps, grout grain
    p["row_shift"] = d.table(256)
    p["tile_value"] = d.table(1024, -1.0, 1.0)
    p["tile_tint"] = d.table(3 * 1024, -1.0, 1.0).view(3, 1024)
    p["tile_tilt"] = d.table(2 * 1024, -1.0, 1.0).view(2, 1024)
    return p


def _draw_layout(d: Draw, layout: str) -> tuple[float, float, float, float]:
    """``(rows per patch unit, tile aspect, bond, row jitter)`` of a layout of tiles."""
    bond, row_jitter = 0.0, 0.0
    if layout == "grid":
        rows, aspect = d.uniform(1.0, 3.5), d.choice([1.0, 1.0, 1.5, 2.0])
    elif layout == "bricks":
        rows, aspect, bond = d.uniform(2.5, 6.0), d.uniform(1.8, 3.2), 0.5
    elif layout == "stack":
        rows, aspect = d.uniform(1.5, 4.0), d.uniform(2.0, 4.0)
    elif layout == "mosaic":
        rows, aspect = d.uniform(5.0, 10.0), 1.0
    else:
        rows, aspect, row_jitter = d.uniform(2.0, 5.0), d.uniform(2.0, 5.0), 1.0
    return rows, aspect, bond, row_jitter


def _draw_style(d: Draw, style: str) -> tuple:
    """``(colour, jitter, mottle, roughness, specular, relief, grout colour)`` of a style of tile."""
    if style == "glazed":
        colour = d.colour((0.0, 1.0), (0.05, 0.7), (0.25, 0.95))
        jitter, mottle = d.uniform(0.0, 0.12), d.uniform(0.0, 0.1)
        rough, spec, relief = d.uniform(0.06, 0.3), d.uniform(0.04, 0.06), d.uniform(0.005, 0.03)
        grout = d.colour((0.0, 1.0), (0.0, 0.1), (0.2, 0.9))
    elif style == "terracotta":
        colour = d.colour((0.02, 0.08), (0.45, 0.75), (0.45, 0.75))
        jitter, mottle = d.uniform(0.08, 0.2), d.uniform(0.1, 0.25)
        rough, spec, relief = d.uniform(0.5, 0.72), d.uniform(0.03, 0.045), d.uniform(0.03, 0.1)
        grout = d.colour((0.06, 0.12), (0.0, 0.2), (0.3, 0.8))
    elif style == "stone":
        colour = d.colour((0.05, 0.12), (0.0, 0.25), (0.35, 0.8))
        jitter, mottle = d.uniform(0.05, 0.15), d.uniform(0.1, 0.25)
        rough, spec, relief = d.uniform(0.35, 0.65), d.uniform(0.03, 0.05), d.uniform(0.02, 0.08)
        grout = d.colour((0.0, 1.0), (0.0, 0.1), (0.2, 0.7))
    else:  # brick
        hue = (0.08, 0.12) if d.chance(0.2) else (-0.02, 0.06)
        colour = d.colour(hue, (0.35, 0.7), (0.25, 0.6))
        jitter, mottle = d.uniform(0.1, 0.35), d.uniform(0.15, 0.35)
        rough, spec, relief = d.uniform(0.55, 0.74), d.uniform(0.03, 0.04), d.uniform(0.05, 0.15)
        grout = d.colour((0.07, 0.12), (0.05, 0.2), (0.45, 0.8))
    return colour, jitter, mottle, rough, spec, relief, grout


def _draw_studs(d: Draw, p: dict[str, Any], layout: str, size: float) -> None:
    """Metal studs (rivets) where four tiles meet, on grids whose corners line up; drawn for every
    material (``studs`` 0: none shown) so that the draws that follow do not depend on it."""
    p["studs"] = 1.0 if layout in ("grid", "stack") and d.chance(0.35) else 0.0
    p["stud_specular"], _ = draw_metal_specular(d)
    p["stud_diffuse"] = grey(d.uniform(0.0, 0.03))
    p["stud_roughness"] = d.uniform(0.15, 0.4)
    p["stud_radius"] = size * d.uniform(0.08, 0.16)
    p["stud_dome"] = d.uniform(0.2, 0.5)  # height over radius


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
    kx, ky = p["columns"], p["rows"]
    b = v * ky
    j = torch.floor(b)
    fb = b - j
    shift = p["bond"] * j + p["row_jitter"] * lookup(p["row_shift"], wrap(j, 256).long())
    a = u * kx + shift
    i = torch.floor(a)
    fa = a - i
    # Distance to the nearest tile edge in patch units.
    edge = torch.minimum(torch.minimum(fa, 1 - fa) / kx, torch.minimum(fb, 1 - fb) / ky)
    gw = p["grout_width"]
    grout = 1 - smoothstep(gw - 0.003, gw + 0.003, edge)
    ramp = ((edge - gw) / p["bevel"]).clamp(0, 1)
    bevel = 1 - (1 - ramp) * (1 - ramp)  # rounded edge: 0 at the grout, 1 on the face
    tile = (wrap(i, 32) * 32 + wrap(j, 32)).long()
    value = lookup(p["tile_value"], tile)
    tint = lookup(p["tile_tint"], tile)
    tilt = lookup(p["tile_tilt"], tile)

    fn = p["noise_freq"]
    n = fbm(p["lattice"], u * fn, v * fn, 4)
    mottle, bump, sand = n[:, 0:1], n[:, 1:2], n[:, 2:3]
    slope = tilt[:, 0:1] * (fa - 0.5) / kx + tilt[:, 1:2] * (fb - 0.5) / ky
    height = bevel * (p["depth"] + p["tilt"] * slope + p["relief"] / fn * bump)
    height = height + grout * (0.3 * p["relief"] / fn) * sand - 0.8 * p["depth"]

    face = p["colour"] * (1 + p["jitter"] * (value + 0.3 * tint)) * (1 + p["mottle"] * mottle)
    diffuse = mix(face, p["grout_colour"] * (1 + 0.15 * sand), grout)
    face_rough = (p["roughness"] * (1 + 0.15 * mottle)).clamp(max=0.65)  # grout stays rougher
    roughness = mix(face_rough, p["grout_roughness"] + 0.03 * sand, grout)
    specular = mix(p["specular"], p["grout_specular"], grout)

    # Studs: domes of metal centred on the tile corners (distance in patch units).
    cx, cy = torch.minimum(fa, 1 - fa) / kx, torch.minimum(fb, 1 - fb) / ky
    r = p["stud_radius"]
    t = (1 - (cx * cx + cy * cy) / (r * r)).clamp(0, 1)  # 1 at the corner, 0 at the rim
    stud = smoothstep(0.0, 0.12, t) * p["studs"]
    top = 0.2 * p["depth"] + p["stud_dome"] * r * t
    height = mix(height, top, stud)
    diffuse = mix(diffuse, p["stud_diffuse"], stud)
    roughness = mix(roughness, p["stud_roughness"], stud)
    specular = mix(specular, p["stud_specular"], stud)
    return Fields(height, diffuse, roughness, specular, {"grout": grout * (1 - stud), "stud": stud})


# weight: a family of the Des18 materials: they keep the bulk of the draws
register(Family("tiles", "tiles, bricks and mosaics with recessed, rougher grout; metal studs", draw, fields,
                order=20, weight=1.0))
