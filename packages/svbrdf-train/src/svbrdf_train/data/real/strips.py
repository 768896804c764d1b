"""Real materials given as maps only: strips of four tiles, photographed on the fly.

A *material strip* is one PNG of four square tiles side by side, ``normal | diffuse |
roughness | specular``, in the map conventions of the Des18 strips without their input tile:
OpenGL normals stored as ``(n + 1) / 2``, linear diffuse and specular albedo, roughness as
stored (alpha = r^2), grey in three channels. Any tile size works. Scanned and artist
materials (ambientCG, cgbookcase, Poly Haven) convert to it from their metal/rough maps
(diffuse = base * (1 - metallic), specular = 0.04 + (base - 0.04) * metallic).

:class:`MaterialStrips` makes a training sample of a strip: a random window covering between
a quarter and the whole of the material (its side 50-100% of the tile's, log-uniform),
resized to the training resolution (area filter, normals renormalised), one of the eight
turns and mirrors of the square (normals turned and mirrored with the pixels), the diffuse
albedo scaled by a factor in ``ALBEDO_SCALE`` that never lifts a pixel above
``ALBEDO_CEILING`` (specular is left alone, so metals stay metals and dielectrics keep their
F0), and the photo rendered under the simulated phone capture of the procedural data
(:mod:`svbrdf_train.data.simulated_photo`: field of view, flash offset, camera shift, exposure,
white balance, noise, clip, JPEG). Every draw follows from ``(seed, epoch, index)``, so a
resumed fit sees the same samples. Without ``augment`` (validation) a sample is the whole
tile, untouched, under a fixed photo of the ``seed``.

The strips are decoded once and held as 8-bit values (:class:`.strip_bank.MaterialBank`; 10
bytes a pixel: 183 MB for 70 materials at 512 px), from a folder of PNGs or from a strip
shard, which holds them already decoded and, if asked, smaller.

Folds keep materials apart: :func:`fold_split` holds out fold ``k/n`` of the materials (a
fixed assignment by a hash of each name, so adding a material moves no other) or the named
ones, for validation on materials the fit never saw.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, decode_normal

from ..seeds import key
from ..simulated_photo import PhotoSettings, draw_photo, photographs
from .des18 import DIHEDRAL_COUNT, dihedral
from .kinds import kind_weights
from .strip_bank import MaterialBank

__all__ = ["ALBEDO_CEILING", "ALBEDO_SCALE", "CROP_SIDE", "MaterialStrips", "StripCrop", "fold_split"]

#: Side of a training window as a share of the tile's side (log-uniform): 0.5 covers a
#: quarter of the material's area, 1 all of it.
CROP_SIDE = (0.5, 1.0)
#: Factor range of the diffuse albedo (log-uniform), and the value no pixel is lifted above.
ALBEDO_SCALE = (0.8, 1.25)
ALBEDO_CEILING = 0.95
#: The stream of a strip's photo draws (beside procedural data's streams in :mod:`..seeds`).
_STRIP_STREAM = 0x5354
#: The stream of the material and albedo draws of a balanced or prior-matched source, apart
#: from the window's, so that a source without them draws what it always drew.
_MIX_STREAM = 0x4B49
#: How far the albedo prior may move a material's diffuse (factor range): a dark wood stays a
#: dark wood, only brighter or darker.
PRIOR_FACTOR = (0.5, 2.0)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _generator(seed: int, epoch: int, index: int, stream: int = _STRIP_STREAM) -> torch.Generator:
    words = np.random.SeedSequence([seed, stream, epoch, index]).generate_state(2, dtype=np.uint32)
    return torch.Generator().manual_seed(int(words[0]) << 32 | int(words[1]))


def _fold_of(name: str, n: int) -> int:
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big") % n


def fold_split(names: Sequence[str], spec: str | None, where: str = "") -> tuple[list[str], list[str]]:
    """``(train, held_out)`` materials of ``names`` under ``spec``.

    ``spec`` is ``"k/n"`` (hold out fold ``k`` of ``n``, 1-based; each material's fold is a
    hash of its name), comma-separated names (exact, or an unambiguous prefix; case-insensitive),
    or None (hold out nothing).

    Raises:
        DataError: a spec that is neither, a name matching no material or several, a fold that
            holds out nothing or everything; the message names the spec and the materials.
    """
    names = list(names)
    if spec is None:
        return names, []
    source = f" in {where}" if where else ""
    text = str(spec).strip()
    parts = text.split("/")
    if len(parts) == 2 and all(p.strip().isdigit() for p in parts):
        k, n = (int(p) for p in parts)
        if not 1 <= k <= n:
            raise DataError(f"fold {spec!r}: expected k/n with 1 <= k <= n (e.g. 1/5)")
        held = [m for m in names if _fold_of(m, n) == k - 1]
    else:
        held = [_match(w.strip(), names, spec, source) for w in text.split(",") if w.strip()]
    if not held:
        raise DataError(
            f"fold {spec!r}: names no material{source}; {len(names)} materials: {', '.join(names[:8])}..."
        )
    train = [m for m in names if m not in set(held)]
    if not train:
        raise DataError(f"fold {spec!r}: holds out every material{source}, leaving none to train on")
    return train, sorted(set(held), key=names.index)


def _match(word: str, names: list[str], spec: str, source: str) -> str:
    exact = [m for m in names if m.lower() == word.lower()]
    hits = exact or [m for m in names if m.lower().startswith(word.lower())]
    if len(hits) != 1:
        what = "is no known material" if not hits else f"could be {' or '.join(hits[:4])}"
        raise DataError(f"fold {spec!r}: {word!r} {what}{source}; give k/n or material names")
    return hits[0]


class StripCrop(NamedTuple):
    """Where a sample's window lies in its material and how it is changed."""

    material: int
    side: int
    top: int
    left: int
    #: 0-3 quarter turns counter-clockwise; 4-7 the same, then a left-right mirror.
    dihedral: int
    #: Factor of the diffuse albedo before the ceiling (1: unchanged).
    albedo: float


def _albedo_factor(drawn: float, brightest: float) -> float:
    """The diffuse factor applied: ``drawn`` when it darkens; when it brightens, at most what
    keeps the brightest pixel at :data:`ALBEDO_CEILING` (and never a darkening instead)."""
    if drawn <= 1.0 or brightest <= 0:
        return drawn if drawn <= 1.0 else 1.0
    return max(1.0, min(drawn, ALBEDO_CEILING / brightest))


def _log_uniform(g: torch.Generator, low: float, high: float) -> float:
    u = float(torch.rand((), generator=g, dtype=torch.float64))
    return math.exp(math.log(low) + (math.log(high) - math.log(low)) * u)


class MaterialStrips(Dataset):
    """``count`` samples an epoch of the materials of ``bank`` (sample ``i`` shows material
    ``i % len(bank)``), at ``resolution`` pixels, photographed under ``photo``.

    Each item is the sample dict of :mod:`svbrdf_train.data.sample` (``input``, ``maps``, ``name`` =
    ``strip:<material>``). See the module doc for the draws; ``augment=False`` gives the
    whole tile under a fixed photo, for validation.

    ``weights`` (one per material; ``balance="kind"``: :func:`.kinds.kind_weights`): sample
    ``i`` shows a material drawn with these weights instead of material ``i % len(bank)``.
    ``albedo_prior`` ``(median, sigma)``: the diffuse of each sample is scaled towards a mean
    luminance drawn log-normally around ``median`` (``sigma`` in natural-log units), by a
    factor within :data:`PRIOR_FACTOR` and under the ceiling, instead of by
    :data:`ALBEDO_SCALE`: the brightness mix then follows the prior, not the sources' level.
    Both act only with ``augment``.
    """

    def __init__(
        self,
        bank: MaterialBank,
        count: int,
        resolution: int,
        *,
        seed: int = 0,
        photo: PhotoSettings | None = None,
        augment: bool = True,
        weights: Sequence[float] | None = None,
        balance: str = "none",
        albedo_prior: tuple[float, float] | None = None,
    ):
        if len(bank) == 0:
            raise DataError(f"{bank.where}: no materials to draw from")
        if bank.tile < resolution:
            raise DataError(
                f"{bank.where}: tiles of {bank.tile} px are smaller than the training resolution "
                f"{resolution}; give strips of at least {resolution} px"
            )
        self.bank, self.count, self.resolution = bank, int(count), int(resolution)
        self.seed, self.augment, self.epoch = int(seed), bool(augment), 0
        self.photo = photo or PhotoSettings()
        self._cumulative = None
        if balance == "kind" and weights is None:
            weights = kind_weights(bank.names)
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            if w.shape != (len(bank),) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
                raise DataError(f"{bank.where}: expected {len(bank)} finite weights >= 0, not all 0")
            self._cumulative = np.cumsum(w) / w.sum()
        self.albedo_prior = None
        if albedo_prior is not None:
            median, sigma = (float(v) for v in albedo_prior)
            if not (0 < median < 1 and 0 <= sigma <= 3):
                raise DataError(
                    f"albedo prior: expected (median in (0, 1), sigma in [0, 3]), got {albedo_prior}"
                )
            self.albedo_prior = (median, sigma)
            self._luminance = [float(_LUMA @ m[3:6].reshape(3, -1).mean(1)) / 255 for m in bank.maps]

    def __len__(self) -> int:
        return self.count

    def set_epoch(self, epoch: int) -> None:
        """Draw other windows, turns and photos from now on."""
        self.epoch = int(epoch)

    def _material(self, index: int) -> tuple[int, float | None]:
        """The material of sample ``index`` and the albedo factor the prior asks (None: no
        prior)."""
        if not self.augment or (self._cumulative is None and self.albedo_prior is None):
            return index % len(self.bank), None
        g = _generator(self.seed, self.epoch, index, _MIX_STREAM)
        u = torch.rand((), generator=g, dtype=torch.float64)
        z = torch.randn((), generator=g, dtype=torch.float64)
        m = index % len(self.bank)
        if self._cumulative is not None:
            m = min(int(np.searchsorted(self._cumulative, float(u), side="right")), len(self.bank) - 1)
        if self.albedo_prior is None:
            return m, None
        median, sigma = self.albedo_prior
        target = median * math.exp(sigma * float(z))
        return m, min(max(target / max(self._luminance[m], 1e-4), PRIOR_FACTOR[0]), PRIOR_FACTOR[1])

    def placement(self, index: int) -> StripCrop:
        """The window, turn and albedo factor of sample ``index`` this epoch."""
        m, prior = self._material(index)
        tile = self.bank.maps[m].shape[-1]
        if not self.augment:
            return StripCrop(m, tile, 0, 0, 0, 1.0)
        g = _generator(self.seed, self.epoch, index)
        low = max(CROP_SIDE[0], self.resolution / tile)
        side = min(tile, max(self.resolution, round(tile * _log_uniform(g, low, CROP_SIDE[1]))))
        top, left = (int(v) for v in torch.randint(0, tile - side + 1, (2,), generator=g))
        k = int(torch.randint(0, DIHEDRAL_COUNT, (1,), generator=g))
        albedo = _log_uniform(g, *ALBEDO_SCALE)
        return StripCrop(m, side, top, left, k, albedo if prior is None else prior)

    def maps(self, index: int) -> SVBRDF:
        """The maps of sample ``index`` ``(1, ...)`` at the resolution."""
        c = self.placement(index)
        window = self.bank.maps[c.material][:, c.top : c.top + c.side, c.left : c.left + c.side]
        v = torch.from_numpy(np.ascontiguousarray(window))[None].float().div_(255)
        if c.side != self.resolution:
            v = F.interpolate(v, size=(self.resolution, self.resolution), mode="area")
        diffuse = v[:, 3:6] * _albedo_factor(c.albedo, float(v[:, 3:6].max()))
        maps = SVBRDF(decode_normal(v[:, 0:3], dim=1), diffuse, v[:, 6:7], v[:, 7:10], validate=False)
        return dihedral(maps, c.dihedral)

    def _photo_seed(self) -> int:
        return key(self.seed, _STRIP_STREAM, self.epoch if self.augment else 0)

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        indices = [self._check(i) for i in indices]
        packed = torch.cat([self.maps(i).pack() for i in indices])
        seed = self._photo_seed()
        photos = photographs(packed, [draw_photo(seed, i, self.photo) for i in indices])
        return [
            {"input": photos[k].contiguous(), "maps": packed[k].contiguous(), "name": self._name(i)}
            for k, i in enumerate(indices)
        ]

    def __getitem__(self, index: int) -> dict[str, Any]:
        return self.__getitems__([index])[0]

    def _check(self, index: int) -> int:
        if not -self.count <= index < self.count:
            raise IndexError(f"MaterialStrips: index {index} out of range for {self.count} samples")
        return index % self.count

    def _name(self, index: int) -> str:
        return f"strip:{self.bank.names[self._material(index)[0]]}"

    def __repr__(self) -> str:
        return (
            f"MaterialStrips({self.bank.where!r}, {len(self.bank)} materials, count={self.count}, "
            f"resolution={self.resolution}, seed={self.seed}, augment={self.augment})"
        )
