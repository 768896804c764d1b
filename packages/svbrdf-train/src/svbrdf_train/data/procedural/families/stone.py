"""The stone family of procedural materials.

Marble with veins, granite, sandstone, slate: domain-warped fBm, specks, polished or rough.
"""

from typing import Any

from torch import Tensor

from ..noise import Draw, fbm, mix, smoothstep
from .base import Family, Fields, register
from .drawing import draw_frame, frame, grey, vary


def draw(d: Draw) -> dict[str, Any]:
    kind = d.choice(["marble", "granite", "sandstone", "slate"], [0.35, 0.25, 0.25, 0.15])
    p = draw_frame(d)
    p["freq"] = d.log_uniform(0.7, 2.5)  # lattice cells per patch unit
    p["warp"] = d.uniform(0.2, 1.4) if kind != "granite" else d.uniform(0.1, 0.5)
    p["gain"] = d.uniform(0.45, 0.62)
    base, second, vein, polished = _draw_look(d, kind, p)
    p["base"], p["second"], p["vein_colour"] = base, second, vein
    p["speck_dark"] = d.colour((0.0, 1.0), (0.0, 0.2), (0.02, 0.15))
    p["speck_light"] = d.colour((0.0, 0.1), (0.0, 0.35), (0.7, 0.95))
    p["speck_freq"] = d.uniform(12.0, 30.0)  # cells per patch unit
    _draw_finish(d, p, polished)
    p["lattice"] = d.lattice(4)  # warp u, warp v, base, veins
    p["grain_lattice"] = d.lattice(3)  # dark specks, light specks, grain
    return p


def _draw_look(d: Draw, kind: str, p: dict[str, Any]) -> tuple[Any, Any, Any, bool]:
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
        second = vary(d, base, (0.75, 1.1))
    elif kind == "granite":
        base = d.colour((0.0, 0.1), (0.0, 0.3), (0.3, 0.7))
        vein = base
        p["vein"], p["vein_width"] = 0.0, 0.1
        p["speck"] = 1.0
        polished = d.chance(0.5)
        second = vary(d, base, (0.7, 1.2))
    elif kind == "sandstone":
        base = d.colour((0.05, 0.13), (0.15, 0.5), (0.45, 0.85))
        vein = vary(d, base, (0.7, 0.9), (1.0, 1.4))
        p["vein"] = d.uniform(0.0, 0.5)
        p["vein_width"] = d.uniform(0.2, 0.5)
        p["speck"] = d.uniform(0.0, 0.4)
        polished = False
        second = vary(d, base, (0.8, 1.15), (0.8, 1.3))
    else:  # slate
        base = d.colour((0.0, 1.0), (0.0, 0.18), (0.1, 0.35))
        vein = vary(d, base, (1.1, 1.5))
        p["vein"] = d.uniform(0.0, 0.4)
        p["vein_width"] = d.uniform(0.1, 0.3)
        p["speck"] = 0.0
        polished = d.chance(0.15)
        second = vary(d, base, (0.8, 1.25))
    return base, second, vein, polished


def _draw_finish(d: Draw, p: dict[str, Any], polished: bool) -> None:
    """Roughness, relief and specular albedo of a polished or a rough stone surface."""
    if polished:
        p["roughness"], p["roughness_var"] = d.uniform(0.1, 0.32), d.uniform(0.0, 0.05)
        p["relief"], p["grain_relief"] = d.uniform(0.0, 0.015), d.uniform(0.0, 0.005)
    else:
        p["roughness"], p["roughness_var"] = d.uniform(0.4, 0.72), d.uniform(0.05, 0.15)
        p["relief"], p["grain_relief"] = d.uniform(0.02, 0.1), d.uniform(0.01, 0.05)
    p["specular"] = grey(d.uniform(0.035, 0.06) if polished else d.uniform(0.03, 0.05))


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
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


# order: drawn from first; weight: a family of the Des18 materials: they keep the bulk of the draws
register(Family("stone", "marble with veins, granite, sandstone, slate (warped fBm)", draw, fields,
                order=10, weight=1.0))
