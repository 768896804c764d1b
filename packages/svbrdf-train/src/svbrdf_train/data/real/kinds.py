"""What kind of material a strip shows, read from its name, and weights that balance kinds.

The real training folders are far from balanced: the second one is mostly stone and ground
(31 and 23 of 121) with two metals and one fabric. Drawn uniformly over materials, a fit
would learn stone's look as the look of the world. :func:`material_kind` reads the kind from
the name the source sites give their sets (ambientCG ``Bricks057``, Texture Haven
``brown_planks_03``): the first rule below whose word the lower-cased name contains, else
``other``. :func:`kind_weights` gives each material ``1 / sqrt(n)`` of its kind's ``n``: a
kind's share grows as the square root of its size, so rare kinds are drawn far more often
than their count says, without one paper set being a twelfth of every batch.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence

__all__ = ["KIND_RULES", "material_kind", "kind_weights"]

#: ``(kind, words)`` in the order they are tried: earlier rules win, so "plaster_brick" is
#: plaster, "moss_wood" wood and "sandstone_blocks" stone, not ground.
KIND_RULES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("metal", ("metal", "steel", "iron", "copper", "brass", "gold", "alumin", "rust", "chrome")),
    ("fabric", ("fabric", "carpet", "cloth", "leather", "wool", "textile")),
    ("paper", ("paper", "cardboard")),
    ("plastic", ("plastic", "rubber")),
    ("tiles", ("tile", "roof", "riet", "pattern", "patern")),
    ("plaster/concrete", ("plaster", "concrete", "stucco", "cement")),
    ("brick", ("brick", "klinker")),
    ("wood", ("wood", "bark", "plank")),
    ("stone", ("sandstone", "marble", "cobble", "granite", "slate", "paving", "blocks", "medieval")),
    ("ground", ("ground", "grass", "mud", "dirt", "soil", "sand", "snow", "ice", "gravel", "pebble",
                "asphalt", "road", "terrain")),
    ("stone", ("rock", "stone")),
)


def material_kind(name: str) -> str:
    """The kind of the material called ``name`` (see :data:`KIND_RULES`), or ``other``."""
    low = name.lower()
    for kind, words in KIND_RULES:
        if any(w in low for w in words):
            return kind
    return "other"


def kind_weights(names: Sequence[str]) -> list[float]:
    """Per material, ``1 / sqrt(n)`` with ``n`` the number of ``names`` of its kind."""
    kinds = [material_kind(n) for n in names]
    count = collections.Counter(kinds)
    return [1.0 / math.sqrt(count[k]) for k in kinds]
