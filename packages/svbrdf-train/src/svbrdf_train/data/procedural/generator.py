"""Procedural SVBRDF materials photographed by a simulated phone: training data with no download.

Every sample is a seeded function of ``(seed, index)``: a material of one of ten
:data:`~.maps.FAMILIES`, drawn with :data:`~.maps.FAMILY_WEIGHTS` (or, with probability
``mix``, two of them blended through a soft noise mask, as Deschaintre et al. 2018 mix
materials), its diffuse albedo shown at a drawn brightness and chroma (from greyer to more
saturated than its palette), its relief scaled by a drawn strength (30% of materials
flattened, some nearly flat), and its photo rendered by svbrdf-render under a jittered phone
flash held a little off the patch's axis (:func:`~svbrdf_train.data.simulated_photo.draw_photo`).
The ranges were moved towards real materials with ``svbrdf-train data compare``
(docs/svbrdf-train.md, "Training data").

=========  ===================================================================
family     what it draws
=========  ===================================================================
stone      marble with veins, granite, sandstone, slate: domain-warped fBm
tiles      tiles, bricks, mosaics; grout recessed, rougher, another colour;
           some with metal studs where the tiles meet
cells      leather, cobbles, cracked earth and paint: Worley cells
wood       rings, fibres, pores; optionally planks with seams
metal      brushed, polished and scratched, hammered, sandblasted, embossed;
           coloured specular (measured F0, or tarnished and anodised: darker),
           dark diffuse
fabric     plain, twill and satin weaves of round threads; stripes and checks
plaster    plaster, stucco, concrete: broad low bumps, stucco dabs, pores and
           air holes (recessed, rougher); near-grey, rough
rusted     painted and rusted steel: paint chipped down to the metal, rust
           patches (orange-brown rough dielectric, flaky) on the bare metal
bark       plates between deep furrows along the trunk (darker, rougher),
           cracks across the plates, weathered tops, lichen
rock       rough rock with strong warped low-frequency relief and folds,
           crevices (darker, rougher), lichen and moss patches
=========  ===================================================================

Example:
    >>> data = ProceduralMaterials(count=1000, resolution=256, seed=0)
    >>> sample = data[3]                       # {"input", "maps", "name"}
    >>> sample["maps"].shape, sample["name"]
    (torch.Size([10, 256, 256]), 'procedural:0:3')
    >>> batch = data.batch([3, 4])             # the same samples, stacked, faster
    >>> batch = data.batch([3, 4], device="cuda")   # computed on a GPU (see below)  # doctest: +SKIP

Reproducibility: the output for ``(seed, index, resolution)`` is the same bytes in any
process, DataLoader worker, thread count and batch (``batch([3, 4])`` equals
``[data[3], data[4]]`` stacked): each sample draws from generators seeded by a hash of
``(seed, index)``, never from the global RNG, and the batched fields use only ops that
compute each sample alike whatever the batch (see :mod:`.noise`). Across
machines the bytes agree where torch runs the same CPU kernels (AVX2 and AVX512 builds
agree; torch's scalar fallback rounds ``grid_sample`` differently in the last bit).
:data:`GENERATOR_VERSION` changes whenever the output on one machine does: by hand for a change
of code, by itself for a change of the family table (see :func:`generator_version`).

On a training device (``batch(indices, device="cuda")``, what ``data.generate: device``
uses): the per-sample draws are made on the CPU as above and copied over, the pixel grid,
fields, normals and photos are computed on the device, the whole batch at once. A sample is
the same material under the same camera, flash and exposure as on the CPU; its values
differ in rounding, and its photo noise is the device generator's draw from the same seed.
The same ``(seed, indices)`` gives the same bytes every time on the same device model.

Where the parts live: :mod:`.maps` draws the materials (their recipes, mixes and maps; the
families themselves are in :mod:`.families`, one module each),
:mod:`svbrdf_train.data.simulated_photo` simulates the phone photo, and this module joins the
two in the data set.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import torch
from torch.utils.data import Dataset

from svbrdf_models.errors import DataError
from svbrdf_render import Scene

from ..simulated_photo import PhotoSettings, draw_photo, photo_jpeg_quality, photo_scene, photographs
from .families import family_fingerprint
from .maps import as_device, check_families, check_index, check_resolution, packed_materials, sample_recipe

__all__ = ["GENERATOR_VERSION", "ProceduralMaterials", "generator_version"]

#: The version of the generator's code: bumped by hand when a change to the code (the recipes,
#: mixing, tone and relief, the capture, a family's ``draw`` or ``fields``) changes the output.
_CODE_VERSION = "3"
#: :func:`~.families.family_fingerprint` of the family table :data:`_CODE_VERSION` was released
#: with (its families, drawing order and weights); set it anew when bumping the code version.
_CODE_VERSION_FAMILIES = "b925ab6a"


def generator_version(fingerprint: str | None = None) -> str:
    """The generator's version for the family table of ``fingerprint`` (default the registered
    one): the code version, followed by ``+`` and the fingerprint when the table is not the one
    that version was released with. Adding, removing, reordering or reweighting a family changes
    the output, so it changes the version, with no edit here."""
    fingerprint = family_fingerprint() if fingerprint is None else fingerprint
    if fingerprint == _CODE_VERSION_FAMILIES:
        return _CODE_VERSION
    return f"{_CODE_VERSION}+{fingerprint}"


#: Changes whenever the output for a given (seed, index, resolution) changes; recorded in shards.
GENERATOR_VERSION = generator_version()


class ProceduralMaterials(Dataset):
    """``count`` procedural samples in the common sample layout (:mod:`svbrdf_train.data.sample`).

    Args:
        count: number of samples (indices ``0 .. count - 1``).
        resolution: square size of the maps and the photo, in pixels (any size).
        seed: selects the whole data set; sample ``i`` depends on ``(seed, i)`` only.
        families: families to draw from (default all :data:`~.maps.FAMILIES`).
        mix: probability that a sample blends two materials through a mask.
        photo: the jitter of the simulated phone photo (default :class:`PhotoSettings`).

    Each item is ``{"input": (3, R, R) linear photo in [0, 1], "maps": (10, R, R),
    "name": "procedural:<seed>:<index>"}``; :meth:`batch` returns the same, stacked.
    """

    def __init__(
        self,
        count: int,
        resolution: int = 256,
        seed: int = 0,
        families: Sequence[str] | None = None,
        mix: float = 0.3,
        photo: PhotoSettings | None = None,
    ):
        count = operator.index(count)
        if count < 0:
            raise DataError(f"count: expected a number of samples >= 0, got {count}")
        if not 0 <= mix <= 1:
            raise DataError(f"mix: expected a probability in [0, 1], got {mix}")
        self.count = count
        self.resolution = check_resolution(resolution)
        self.seed = operator.index(seed)
        self.families = check_families(families)
        self.mix = float(mix)
        self.photo = photo or PhotoSettings()

    def __len__(self) -> int:
        return self.count

    def __repr__(self) -> str:
        return (
            f"ProceduralMaterials(count={self.count}, resolution={self.resolution}, seed={self.seed}, "
            f"families={list(self.families)}, mix={self.mix})"
        )

    def family(self, index: int) -> str:
        """The family name of sample ``index`` (cheap: nothing is generated)."""
        i = check_index(index, self.count)
        return sample_recipe(self.seed, i, self.families, self.mix, None).family

    def scene(self, index: int) -> Scene:
        """The simulated phone flash that photographs sample ``index``."""
        return photo_scene(self.seed, check_index(index, self.count), self.photo)

    def jpeg_quality(self, index: int) -> int | None:
        """The JPEG quality of sample ``index``'s photo, or None: not JPEG-compressed."""
        return photo_jpeg_quality(self.seed, check_index(index, self.count), self.photo)

    def __getitem__(self, index: int) -> dict[str, Any]:
        b = self.batch([index])
        return {"input": b["input"][0], "maps": b["maps"][0], "name": b["name"][0]}

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """What a DataLoader fetches for one batch: generated together (see :meth:`batch`)."""
        b = self.batch(indices)
        return [
            {"input": b["input"][k], "maps": b["maps"][k], "name": b["name"][k]} for k in range(len(indices))
        ]

    def batch(self, indices: Sequence[int], device: torch.device | str | None = None) -> dict[str, Any]:
        """Samples ``indices`` stacked: ``input`` ``(B, 3, R, R)``, ``maps`` ``(B, 10, R, R)``,
        ``name`` a list. The same values as one by one, in less time.

        ``device``: where the maps and photos are computed and returned (default the CPU,
        whose bytes are the reference :data:`GENERATOR_VERSION` tracks). The random draws
        stay on the CPU (they define the distribution), so on any device a sample is the
        same material under the same camera, flash and exposure; an accelerator computes it
        in one pass over the whole batch and one render, with values that differ from the
        CPU's in rounding, and photo noise drawn by the device's own generator from the
        same seed: other noise than the CPU's, the same bytes every time on that device.
        """
        indices = [check_index(i, self.count) for i in indices]
        device = as_device(device)
        packed, _ = packed_materials(
            self.seed, indices, self.resolution, self.families, self.mix, None, device
        )
        return {
            "input": photographs(packed, [draw_photo(self.seed, i, self.photo) for i in indices]),
            "maps": packed,
            "name": [f"procedural:{self.seed}:{i}" for i in indices],
        }
