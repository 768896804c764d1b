"""Procedural training data: materials drawn from seeded families and photographed by a
simulated phone, with nothing to download.

- :mod:`.generator`: the data set (:class:`ProceduralMaterials`) and the generator's version;
- :mod:`.maps`: a sample's recipe (one family or a mix of two), its maps and their tone;
- :mod:`.families`: the material families, one module each;
- :mod:`.noise`: the batched noise the families draw with, and a material's random draws.

The photo is the shared :mod:`svbrdf_train.data.simulated_photo`'s, which the real material
strips use too; nothing here imports :mod:`svbrdf_train.data.real` or the shards.
"""

from __future__ import annotations

from .generator import GENERATOR_VERSION, ProceduralMaterials, generator_version
from .maps import FAMILIES, FAMILY_WEIGHTS, material, materials

__all__ = [
    "FAMILIES",
    "FAMILY_WEIGHTS",
    "GENERATOR_VERSION",
    "ProceduralMaterials",
    "generator_version",
    "material",
    "materials",
]
