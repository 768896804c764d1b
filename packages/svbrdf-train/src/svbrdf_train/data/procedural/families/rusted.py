"""The rusted family of procedural materials.

Painted and rusted steel: paint chipped down to the metal, rust patches (orange-brown rough
dielectric, flaky) on the bare metal.
"""

from typing import Any

from torch import Tensor

from ...stats import LUMINANCE
from ..noise import Draw, fbm, mix, smoothstep
from .base import Family, Fields, register
from .drawing import METALS, draw_frame, frame, grey

#: Metals that rust or carry paint: steel and iron, and the greyer coatings of sheet metal.
_SHEET_METALS = ("iron", "chromium", "nickel", "zinc", "aluminium", "cobalt")


def draw(d: Draw) -> dict[str, Any]:
    kind = d.choice(["rusted", "painted", "peeling"], [0.4, 0.3, 0.3])
    p = draw_frame(d)
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


def fields(p: dict[str, Tensor], x: Tensor, y: Tensor) -> Fields:
    u, v = frame(p, x, y)
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


# weight: the most of the surfaces Des18 lacks: metal and dielectric in one
register(Family("rusted", "painted and rusted metal: paint chipped to the metal, rust patches", draw, fields,
                order=80, weight=0.7))
