"""The material families of the procedural generator: one module each, what it draws and computes.

A family is two functions (see :class:`~.base.Family`), written in its own module, which ends
by registering them into :data:`FAMILY_TABLE` (:func:`~.base.register`) with the family's place
in the drawing order (``order``) and how often it is drawn (``weight``):

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
every scale. The helpers the families share (pattern frames, colour variations, the
metals) are in :mod:`.drawing`.

Only the ops listed in :mod:`..noise` touch batched tensors, so that a batch
computes what its members compute alone, bit for bit.

Every family module has the same form: its docstring names the family and describes the
materials it draws; it defines ``draw`` and ``fields`` (and private helpers of its own),
importing only what it uses; and it ends with one statement that registers the two, with the
family's name, a one-line description, its ``order`` and its ``weight``, and the reasons for
them in a comment above it::

    # weight: a surface Des18 lacks
    register(Family("wood", "rings, fibres and pores, optionally planks with seams", draw, fields,
                    order=40, weight=0.6))

Adding a family is adding one such module here, and nothing else names it: this package
imports every module in it (:func:`_import_modules`; a module that registers nothing, as
:mod:`.base` and :mod:`.drawing`, is a helper), the table lists the families by their
declared ``order`` (the drawing order: a sample picks its family by position in it, so it is
part of the generator's output; a new family usually goes last), and
:data:`svbrdf_train.data.procedural.maps.FAMILY_WEIGHTS` and the family part of
:data:`svbrdf_train.data.procedural.GENERATOR_VERSION` are read from the table.
"""

from __future__ import annotations

import importlib
import pkgutil

import torch

from ..noise import Draw
from .base import FAMILY_TABLE, Family, Fields, family_fingerprint, pixel_grid, register, stack_choices
from .drawing import COLOURED_METALS, METALS, draw_metal_specular, grey

__all__ = [
    "COLOURED_METALS",
    "FAMILY_TABLE",
    "METALS",
    "Family",
    "Fields",
    "draw_metal_specular",
    "family_fields",
    "family_fingerprint",
    "grey",
    "pixel_grid",
    "register",
    "stack_choices",
]


def _import_modules() -> None:
    """Import every module of this package (in any order: :func:`register` keeps the table in
    the declared order), so that each family module registers its family."""
    for module in pkgutil.iter_modules(__path__):
        if not module.name.startswith("_"):
            importlib.import_module(f"{__name__}.{module.name}")


_import_modules()


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
