"""The material families of the procedural generator, under their former module name.

The families live in :mod:`svbrdf_train.data.families`, one module each; this module
re-exports the names that were imported from here.
"""

from __future__ import annotations

from .families import (
    COLOURED_METALS,
    FAMILY_TABLE,
    METALS,
    Family,
    Fields,
    draw_metal_specular,
    family_fields,
    grey,
    pixel_grid,
    stack_choices,
)

__all__ = [
    "COLOURED_METALS",
    "FAMILY_TABLE",
    "METALS",
    "Family",
    "Fields",
    "draw_metal_specular",
    "family_fields",
    "grey",
    "pixel_grid",
    "stack_choices",
]
