"""The material families of the procedural generator: what each one draws and computes.

A family is two functions (see :class:`Family`):

- ``draw(d)`` makes the random choices of *one* material from its own :class:`Draw`
  (variant, scale, rotation, palette, finish, random tables) and returns them as a dict
  of Python floats, RGB tuples and tensors;
- ``fields(p, x, y)`` computes the maps of a *batch* of materials of that family from the
  stacked choices ``p`` (floats become ``(B, 1, 1, 1)``, RGB tuples ``(B, 3, 1, 1)``,
  tensors gain a leading ``B``) at pixel positions ``x, y`` in patch units, on the device
  where ``x``, ``y`` and ``p`` lie (:func:`pixel_grid` and :func:`stack_choices` take one).

Fields are the maps before normals: a height in patch units (the patch spans
``[-1, 1]^2``; normals come from its slopes; about zero on average, so that two families
blend without a cliff), linear diffuse and specular albedos, and roughness, all
``(B, C, H, W)`` and not yet clamped. ``parts`` names masks of structural
parts (grout, gaps, grooves) for tests and inspection.

Physical plausibility, by construction: dielectrics have grey specular albedo in
[0.025, 0.06]; metals (the metal family, and the studs of some tiles) a coloured one with
a dark diffuse albedo: a measured F0 of a real metal (linear, mean >= 0.5), or, for
tarnished, oxidised and anodised metal, as Des18's metals mostly are, the same or a dyed
colour at a luminance of 0.09-0.3, still above every dielectric; recessed structure
(grout, gaps, cracks, grooves) is rougher than the surface around it. Heights are drawn
as *slopes* and divided by the pattern's frequency, so a bump looks equally steep at
every scale.

Only the ops listed in :mod:`.procedural_noise` touch batched tensors, so that a batch
computes what its members compute alone, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor

from .procedural_noise import (
    CELL_PERIOD,
    Draw,
    fbm,
    fract,
    lookup,
    mix,
    sample_lattice,
    smoothstep,
    worley,
    wrap,
)
from .stats import LUMINANCE

__all__ = ["Fields", "Family", "FAMILY_TABLE", "stack_choices", "grey", "pixel_grid", "family_fields"]


class Fields(NamedTuple):
    """Maps of a batch before normals (see the module docstring)."""

    height: Tensor  # (B, 1, H, W), patch units
    diffuse: Tensor  # (B, 3, H, W), linear
    roughness: Tensor  # (B, 1, H, W)
    specular: Tensor  # (B, 3, H, W), linear
    parts: dict[str, Tensor]  # name -> (B, 1, H, W) mask in [0, 1]


@dataclass(frozen=True)
class Family:
    """One family of materials: its description and its two functions."""

    name: str
    description: str
    draw: Callable[[Draw], dict[str, Any]]
    fields: Callable[[dict[str, Tensor], Tensor, Tensor], Fields]


def grey(value: float) -> tuple[float, float, float]:
    return (value, value, value)


def stack_choices(
    choices: list[dict[str, Any]], device: torch.device | str | None = None
) -> dict[str, Tensor]:
    """Per-material choices -> batched tensors: floats ``(B, 1, 1, 1)``, RGB ``(B, 3, 1, 1)``,
    tensors ``(B, ...)``; on ``device`` when given (stacked on the CPU, then copied over
    together: one transfer of every float32 table instead of one per key)."""
    out = {}
    for key in choices[0]:
        values = [c[key] for c in choices]
        if isinstance(values[0], Tensor):
            out[key] = torch.stack(values)
        else:
            t = torch.tensor(values, dtype=torch.float32)
            out[key] = t.view(len(values), -1, 1, 1)
    if device is None or torch.device(device).type == "cpu":
        return out
    return _to_device(out, torch.device(device))


def _to_device(tensors: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    """``tensors`` on ``device``: the float32 ones packed into one buffer and copied at once
    (a copy per tensor costs a transfer's latency each), the others one by one."""
    floats = [k for k, t in tensors.items() if t.dtype == torch.float32]
    out = {k: t.to(device) for k, t in tensors.items() if t.dtype != torch.float32}
    if floats:
        flat = torch.cat([tensors[k].reshape(-1) for k in floats]).to(device)
        sizes = [tensors[k].numel() for k in floats]
        for k, part in zip(floats, torch.split(flat, sizes), strict=True):
            out[k] = part.view(tensors[k].shape)
    return {k: out[k] for k in tensors}


# -- shared pieces -------------------------------------------------------------------------


def _draw_frame(d: Draw, aligned: float = 0.0) -> dict[str, float]:
    """A rotation and a shift of the pattern. With probability ``aligned`` the rotation is a
    quarter turn plus a few degrees (tiles and planks are usually shot square)."""
    if d.chance(aligned):
        a = d.integer(0, 3) * math.pi / 2 + math.radians(d.uniform(-4.0, 4.0))
        cs, sn = math.cos(a), math.sin(a)
    else:
        cs, sn = d.angle()
    return {"cos": cs, "sin": sn, "shift_u": d.uniform(0.0, 64.0), "shift_v": d.uniform(0.0, 64.0)}


def _frame(p: dict[str, Tensor], x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Pattern coordinates ``(B, 1, H, W)``: the pixel positions rotated, then shifted."""
    u = x * p["cos"] - y * p["sin"] + p["shift_u"]
    v = x * p["sin"] + y * p["cos"] + p["shift_v"]
    return u, v


def _vary(d: Draw, rgb, value: tuple[float, float], saturation: tuple[float, float] = (1.0, 1.0)):
    """A second colour near ``rgb``: brightness scaled by ``value``, chroma by ``saturation``."""
    k, s = d.uniform(*value), d.uniform(*saturation)
    mean = sum(rgb) / 3
    return tuple(min(max(k * (mean + s * (c - mean)), 0.0), 1.0) for c in rgb)


# -- stone: marble, granite, sandstone, slate ----------------------------------------------


def _draw_stone(d: Draw) -> dict[str, Any]:
    kind = d.choice(["marble", "granite", "sandstone", "slate"], [0.35, 0.25, 0.25, 0.15])
    p = _draw_frame(d)
    p["freq"] = d.log_uniform(0.7, 2.5)  # lattice cells per patch unit
    p["warp"] = d.uniform(0.2, 1.4) if kind != "granite" else d.uniform(0.1, 0.5)
    p["gain"] = d.uniform(0.45, 0.62)
    base, second, vein, polished = _draw_stone_look(d, kind, p)
    p["base"], p["second"], p["vein_colour"] = base, second, vein
    p["speck_dark"] = d.colour((0.0, 1.0), (0.0, 0.2), (0.02, 0.15))
    p["speck_light"] = d.colour((0.0, 0.1), (0.0, 0.35), (0.7, 0.95))
    p["speck_freq"] = d.uniform(12.0, 30.0)  # cells per patch unit
    _draw_stone_finish(d, p, polished)
    p["lattice"] = d.lattice(4)  # warp u, warp v, base, veins
    p["grain_lattice"] = d.lattice(3)  # dark specks, light specks, grain
    return p


def _draw_stone_look(d: Draw, kind: str, p: dict[str, Any]) -> tuple[Any, Any, Any, bool]:
    """The colours of one kind of stone and whether it is polished: ``(base, second, vein,
    polished)``; sets the strength and width of its veins and specks in ``p``."""
    vein_light = ((0.0, 1.0), (0.0, 0.08), (0.82, 0.97))
    if kind == "marble":
        tone = d.choice(["white", "dark", "coloured"], [0.5, 0.2, 0.3])
        if tone == "white":
            base = d.colour((0.0, 1.0), (0.0, 0.07), (0.75, 0.95))
            vein = d.colour((0.05, 0.12), (0.0, 0.45), (0.25, 0.6))
        elif tone == "dark":
            base = d.colour((0.0, 1.0), (0.0, 0.15), (0.06, 0.22))
            vein = d.colour(*vein_light)
        else:
            hue = d.choice([(0.95, 1.08), (0.25, 0.45), (0.05, 0.12)])
            base = d.colour(hue, (0.15, 0.55), (0.25, 0.75))
            vein = d.colour(*vein_light)
        p["vein"] = d.uniform(0.6, 1.0)
        p["vein_width"] = d.uniform(0.04, 0.12)
        p["speck"] = 0.0
        polished = d.chance(0.7)
        second = _vary(d, base, (0.75, 1.1))
    elif kind == "granite":
        base = d.colour((0.0, 0.1), (0.0, 0.3), (0.3, 0.7))
        vein = base
        p["vein"], p["vein_width"] = 0.0, 0.1
        p["speck"] = 1.0
        polished = d.chance(0.5)
        second = _vary(d, base, (0.7, 1.2))
    elif kind == "sandstone":
        base = d.colour((0.05, 0.13), (0.15, 0.5), (0.45, 0.85))
        vein = _vary(d, base, (0.7, 0.9), (1.0, 1.4))
        p["vein"] = d.uniform(0.0, 0.5)
        p["vein_width"] = d.uniform(0.2, 0.5)
        p["speck"] = d.uniform(0.0, 0.4)
        polished = False
        second = _vary(d, base, (0.8, 1.15), (0.8, 1.3))
    else:  # slate
        base = d.colour((0.0, 1.0), (0.0, 0.18), (0.1, 0.35))
        vein = _vary(d, base, (1.1, 1.5))
        p["vein"] = d.uniform(0.0, 0.4)
        p["vein_width"] = d.uniform(0.1, 0.3)
        p["speck"] = 0.0
        polished = d.chance(0.15)
        second = _vary(d, base, (0.8, 1.25))
    return base, second, vein, polished


def _draw_stone_finish(d: Draw, p: dict[str, Any], polished: bool) -> None:
    """Roughness, relief and specular albedo of a polished or a rough stone surface."""
    if polished:
        p["roughness"], p["roughness_var"] = d.uniform(0.1, 0.32), d.uniform(0.0, 0.05)
        p["relief"], p["grain_relief"] = d.uniform(0.0, 0.015), d.uniform(0.0, 0.005)
    else:
        p["roughness"], p["roughness_var"] = d.uniform(0.4, 0.72), d.uniform(0.05, 0.15)
        p["relief"], p["grain_relief"] = d.uniform(0.02, 0.1), d.uniform(0.01, 0.05)
    p["specular"] = grey(d.uniform(0.035, 0.06) if polished else d.uniform(0.03, 0.05))


def _stone(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
    f = p["freq"]
    uf, vf = u * f, v * f
    warp = fbm(p["lattice"][:, 0:2], uf, vf, 3)
    uw, vw = uf + warp[:, 0:1] * p["warp"], vf + warp[:, 1:2] * p["warp"]
    n = fbm(p["lattice"][:, 2:4], uw, vw, 5, p["gain"])
    base, vein_noise = n[:, 0:1], n[:, 1:2]
    # Veins: thin ridges where the second warped noise crosses zero.
    vein = (1 - vein_noise.abs() / p["vein_width"]).clamp(0, 1)
    vein = vein * vein * p["vein"]
    fs = p["speck_freq"]
    g = fbm(p["grain_lattice"], u * fs, v * fs, 2)
    dark = smoothstep(0.45, 0.6, g[:, 0:1]) * p["speck"]
    light = smoothstep(0.5, 0.65, g[:, 1:2]) * p["speck"]
    grain = g[:, 2:3]

    diffuse = mix(p["base"], p["second"], smoothstep(-0.8, 0.8, base))
    diffuse = mix(diffuse, p["vein_colour"], vein)
    diffuse = mix(diffuse, p["speck_dark"], dark)
    diffuse = mix(diffuse, p["speck_light"], light)
    height = p["relief"] / f * (base - 0.3 * vein) + p["grain_relief"] / fs * grain
    roughness = p["roughness"] + p["roughness_var"] * (0.5 * base + 0.5 * grain)
    return Fields(height, diffuse, roughness, p["specular"].expand_as(diffuse), {"vein": vein})


# -- tiles and bricks with grout -----------------------------------------------------------


def _draw_tiles(d: Draw) -> dict[str, Any]:
    layout = d.choice(["grid", "bricks", "stack", "mosaic", "random bond"], [0.3, 0.3, 0.1, 0.15, 0.15])
    p = _draw_frame(d, aligned=0.75)
    rows, aspect, bond, row_jitter = _draw_tile_layout(d, layout)
    p["rows"], p["columns"], p["bond"], p["row_jitter"] = rows, rows / aspect, bond, row_jitter
    brick = layout in ("bricks", "random bond")
    style = "brick" if brick else d.choice(["glazed", "terracotta", "stone"], [0.5, 0.25, 0.25])
    colour, jitter, mottle, rough, spec, relief, grout = _draw_tile_style(d, style)
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


def _draw_tile_layout(d: Draw, layout: str) -> tuple[float, float, float, float]:
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


def _draw_tile_style(d: Draw, style: str) -> tuple:
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


def _tiles(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


# -- cells: leather, cobbles, cracked earth and paint --------------------------------------


def _draw_cells(d: Draw) -> dict[str, Any]:
    kind = d.choice(["leather", "cobbles", "cracked"], [0.4, 0.3, 0.3])
    p = _draw_frame(d)
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
        p["base"], p["second"] = base, _vary(d, base, (0.85, 1.1))
        p["gap_colour"] = _vary(d, base, (0.45, 0.8), (1.0, 1.2))
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
        p["base"], p["second"] = base, _vary(d, base, (0.85, 1.1))
        p["gap_colour"] = _vary(d, base, (0.15, 0.4))
        p["cell_jitter"], p["multi"] = d.uniform(0.02, 0.1), 0.2
        p["gap_roughness"] = d.uniform(0.75, 0.92)
        p["grain"] = d.uniform(0.03, 0.1)
    p["grain_freq"] = p["freq"] * d.uniform(4.0, 8.0)
    p["points"] = d.cells(regularity)
    p["cell_values"] = d.table(2 * CELL_PERIOD * CELL_PERIOD, -1.0, 1.0).view(2, -1)
    p["lattice"] = d.lattice(2)  # grain, mottling
    return p


def _cells(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


# -- wood: rings, fibres, pores, optional planks -------------------------------------------


def _draw_wood(d: Draw) -> dict[str, Any]:
    p = _draw_frame(d, aligned=0.5)
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
    p["early"], p["late"] = early, _vary(d, early, (0.45, 0.8), (1.0, 1.3))
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


def _wood(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    a, b = _frame(p, x, y)  # a along the grain
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


# -- metal: brushed, scratched, hammered, sandblasted --------------------------------------

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


def _draw_metal(d: Draw) -> dict[str, Any]:
    p = _draw_frame(d)
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


def _metal(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)  # u along the brushing
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


# -- fabric: woven threads -----------------------------------------------------------------


def _draw_fabric(d: Draw) -> dict[str, Any]:
    p = _draw_frame(d, aligned=0.5)
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
        weft = _vary(d, warp, (0.6, 1.3))
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


def _fabric(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


# -- plaster: plaster, stucco, concrete ----------------------------------------------------


def _draw_plaster(d: Draw) -> dict[str, Any]:
    kind = d.choice(["plaster", "stucco", "concrete"], [0.35, 0.3, 0.35])
    p = _draw_frame(d)
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
        base = d.colour((0.05, 0.15), (0.0, 0.25), (0.45, 0.95)) if d.chance(0.6) else d.colour(
            (0.0, 1.0), (0.05, 0.4), (0.3, 0.85)
        )
    p["base"] = base
    p["stain_colour"] = _vary(d, base, (0.4, 0.8), (0.8, 1.5))  # damp, dirt, weathering
    p["stain"] = d.uniform(0.0, 0.7)
    p["mottle"] = d.uniform(0.02, 0.12)
    p["roughness"] = d.uniform(0.6, 0.82)
    p["roughness_var"] = d.uniform(0.02, 0.08)
    p["specular"] = grey(d.uniform(0.025, 0.04))
    p["points"] = d.cells(d.uniform(0.0, 0.4))
    p["pore_table"] = d.table(CELL_PERIOD * CELL_PERIOD)
    p["lattice"] = d.lattice(4)  # bumps, stains, dabs, grain
    return p


def _plaster(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


# -- rusted: painted and rusted metal ------------------------------------------------------

#: Metals that rust or carry paint: steel and iron, and the greyer coatings of sheet metal.
_SHEET_METALS = ("iron", "chromium", "nickel", "zinc", "aluminium", "cobalt")


def _draw_rusted(d: Draw) -> dict[str, Any]:
    kind = d.choice(["rusted", "painted", "peeling"], [0.4, 0.3, 0.3])
    p = _draw_frame(d)
    f0 = METALS[d.choice(_SHEET_METALS)]
    if d.chance(0.4):  # bare, clean metal
        p["metal_specular"] = tuple(d.uniform(0.9, 1.0) * c for c in f0)
    else:  # darkened, oxidised steel: the same colour at a luminance of 0.09-0.3
        level = d.log_uniform(0.09, 0.3)
        lum = sum(w * c for w, c in zip(LUMINANCE, f0, strict=True))
        p["metal_specular"] = tuple(min(c * level / lum, 1.0) for c in f0)
    p["metal_diffuse"] = grey(d.uniform(0.0, 0.03))
    p["metal_roughness"] = d.uniform(0.2, 0.5)
    p["freq"] = d.log_uniform(0.8, 3.0)  # patches of rust and paint, cells per patch unit
    p["gain"] = d.uniform(0.5, 0.65)
    # Paint covers the metal but where it chipped off (chips: sharp edges).
    p["paint"] = 0.0 if kind == "rusted" else 1.0
    p["chip_level"] = d.uniform(-0.1, 0.5) if kind == "painted" else d.uniform(-0.4, 0.1)
    p["paint_colour"] = d.colour((0.0, 1.0), (0.2, 0.85), (0.2, 0.85))
    p["paint_roughness"] = d.uniform(0.25, 0.6)
    p["paint_specular"] = grey(d.uniform(0.035, 0.05))
    p["paint_thickness"] = d.uniform(0.002, 0.008)  # patch units
    # Rust: orange-brown, rough, raised and flaky, on the bare metal only.
    p["rust_level"] = d.uniform(-0.3, 0.3) if kind != "painted" else d.uniform(-0.2, 0.4)
    p["rust_soft"] = d.uniform(0.05, 0.3)
    p["rust_light"] = d.colour((0.03, 0.08), (0.6, 0.9), (0.35, 0.65))
    p["rust_dark"] = d.colour((0.0, 0.06), (0.5, 0.9), (0.1, 0.3))
    p["rust_roughness"] = d.uniform(0.7, 0.9)
    p["rust_specular"] = grey(d.uniform(0.025, 0.035))
    p["flake_freq"] = d.uniform(15.0, 45.0)
    p["flake_relief"] = d.uniform(0.05, 0.2)  # slope of the rust's flakes and pits
    p["rust_thickness"] = d.uniform(0.0, 0.006)
    p["lattice"] = d.lattice(5)  # rust, chips, mottling; flakes, colour
    return p


def _rusted(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
    f, ff = p["freq"], p["flake_freq"]
    n = fbm(p["lattice"][:, 0:3], u * f, v * f, 5, p["gain"])
    fine = fbm(p["lattice"][:, 3:5], u * ff, v * ff, 2)
    flake, tone = fine[:, 0:1], fine[:, 1:2]
    chip = smoothstep(p["chip_level"], p["chip_level"] + 0.04, n[:, 1:2])  # 1 where chipped
    paint = p["paint"] * (1 - chip)
    rs = p["rust_soft"]
    rusty = smoothstep(p["rust_level"] - rs, p["rust_level"] + rs, n[:, 0:1] + 0.15 * flake)
    rust, metal = rusty * (1 - paint), (1 - rusty) * (1 - paint)  # what shows: paint, rust, metal
    mottle = n[:, 2:3]

    rust_colour = mix(p["rust_dark"], p["rust_light"], smoothstep(-0.7, 0.7, tone + 0.5 * mottle))
    paint_colour = p["paint_colour"] * (1 + 0.1 * mottle)
    diffuse = mix(mix(p["metal_diffuse"], rust_colour, rusty), paint_colour, paint)
    specular = mix(mix(p["metal_specular"], p["rust_specular"], rusty), p["paint_specular"], paint)
    roughness = mix(
        mix(p["metal_roughness"] + 0.05 * flake, p["rust_roughness"] + 0.05 * flake, rusty),
        p["paint_roughness"] + 0.03 * mottle,
        paint,
    )
    height = (
        p["paint_thickness"] * paint
        + rust * (p["rust_thickness"] + p["flake_relief"] / ff * flake)
        + 0.2 * p["flake_relief"] / ff * flake * metal  # pitted under the rust
    )
    parts = {"metal": metal, "rust": rust, "paint": paint}
    return Fields(height, diffuse, roughness, specular, parts)


# -- bark: plates and deep furrows ---------------------------------------------------------


def _draw_bark(d: Draw) -> dict[str, Any]:
    p = _draw_frame(d, aligned=0.6)  # v along the trunk: furrows run along v
    p["across"] = d.uniform(2.0, 7.0)  # furrows per patch unit, about
    p["along"] = p["across"] * d.uniform(0.05, 0.15)  # long plates
    p["warp"], p["warp_freq"] = d.uniform(0.05, 0.3), d.uniform(0.5, 1.5)
    p["level"] = d.uniform(-0.25, 0.15)  # where plates end and furrows begin
    p["edge"] = d.uniform(0.08, 0.3)
    p["depth"] = d.uniform(0.25, 0.7)  # slope of the plates' flanks
    p["cracks"], p["crack_freq"] = d.uniform(0.0, 1.0), d.uniform(3.0, 8.0)
    p["fibre_relief"] = d.uniform(0.02, 0.08)
    base = d.colour((0.03, 0.1), (0.2, 0.6), (0.12, 0.45)) if d.chance(0.7) else d.colour(
        (0.0, 1.0), (0.0, 0.12), (0.2, 0.55)
    )
    p["base"] = base
    p["weathered"] = _vary(d, base, (1.0, 1.6), (0.2, 0.6))  # grey, sun-bleached plate tops
    p["weather"] = d.uniform(0.0, 0.7)
    p["furrow_colour"] = _vary(d, base, (0.25, 0.6), (1.0, 1.3))
    p["lichen"] = d.uniform(0.3, 1.0) if d.chance(0.3) else 0.0
    p["lichen_colour"] = d.colour((0.12, 0.3), (0.15, 0.5), (0.4, 0.75))
    p["lichen_level"] = d.uniform(0.0, 0.4)
    p["roughness"] = d.uniform(0.6, 0.8)
    p["furrow_roughness"] = d.uniform(0.84, 0.95)
    p["specular"] = grey(d.uniform(0.025, 0.04))
    p["lattice"] = d.lattice(5)  # warp, plates, cracks, fibres, lichen
    return p


def _bark(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


# -- rock: rough rock with strong relief, crevices, lichen ---------------------------------


def _draw_rock(d: Draw) -> dict[str, Any]:
    p = _draw_frame(d)
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
    p["base"], p["second"] = base, _vary(d, base, (0.6, 1.3), (0.7, 1.5))
    p["crevice_colour"] = _vary(d, base, (0.2, 0.5))
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


def _rock(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = _frame(p, x, y)
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


FAMILY_TABLE: dict[str, Family] = {
    f.name: f
    for f in (
        Family("stone", "marble with veins, granite, sandstone, slate (warped fBm)", _draw_stone, _stone),
        Family(
            "tiles",
            "tiles, bricks and mosaics with recessed, rougher grout; metal studs",
            _draw_tiles,
            _tiles,
        ),
        Family("cells", "leather, cobbles, cracked earth and paint (Worley cells)", _draw_cells, _cells),
        Family("wood", "rings, fibres and pores, optionally planks with seams", _draw_wood, _wood),
        Family(
            "metal", "brushed, polished and scratched, hammered, sandblasted, embossed", _draw_metal, _metal
        ),
        Family("fabric", "plain, twill and satin weaves, stripes and checks", _draw_fabric, _fabric),
        Family("plaster", "plaster, stucco and concrete: broad bumps, dabs, pores", _draw_plaster, _plaster),
        Family(
            "rusted",
            "painted and rusted metal: paint chipped to the metal, rust patches",
            _draw_rusted,
            _rusted,
        ),
        Family("bark", "bark: plates between deep furrows, cracks, lichen", _draw_bark, _bark),
        Family("rock", "rough rock: strong warped relief, crevices, lichen and moss", _draw_rock, _rock),
    )
}


def pixel_grid(
    resolution: int, margin: int = 0, device: torch.device | str | None = None
) -> tuple[Tensor, Tensor]:
    """Pixel centres in patch units, with ``margin`` extra pixels on every side.

    ``x`` ``(1, 1, 1, R + 2m)`` left to right, ``y`` ``(1, 1, R + 2m, 1)`` top (``+1``) to
    bottom, as :func:`svbrdf_render.surface_positions` places them; made on ``device``
    (default the CPU), so that the fields computed from them are computed there.
    """
    n = resolution + 2 * margin
    t = ((torch.arange(n, dtype=torch.float32, device=device) - margin) * 2 + 1) / resolution - 1
    return t.view(1, 1, 1, -1), (-t).view(1, 1, -1, 1)


def family_fields(
    name: str, seeds: list[int], resolution: int, device: torch.device | str | None = None
) -> Fields:
    """The fields of materials of one family drawn from ``seeds`` (for tests and inspection),
    computed on ``device`` (default the CPU)."""
    family = FAMILY_TABLE[name]
    x, y = pixel_grid(resolution, device=device)
    with torch.no_grad():
        f = family.fields(stack_choices([family.draw(Draw(s)) for s in seeds], device), x, y)
    size = (-1, -1, resolution, resolution)
    return Fields(*(t.expand(*size) for t in f[:4]), {k: m.expand(*size) for k, m in f.parts.items()})
