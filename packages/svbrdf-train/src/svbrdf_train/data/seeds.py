"""Seeds of a procedural sample's random streams: the same integers in every process.

Sample ``index`` of data set ``seed`` draws each of its parts (its material, its photo, the
components of a mix, the mixing mask) from a :class:`Stream` of its own (a material's is the
:class:`~svbrdf_train.data.procedural.noise.Draw`, which also draws noise tables), seeded by
:func:`key` of ``(seed, index, stream, ...)``: a part is drawn whatever the others draw, and
never from the global RNG, so a sample is the same in any process, worker and batch.
"""

from __future__ import annotations

import math

import torch

__all__ = ["COMPONENT", "MASK", "MATERIAL", "PHOTO", "Stream", "key"]

#: The stream of a sample's material recipe.
MATERIAL = 1
#: The stream of its photo (:mod:`svbrdf_train.data.simulated_photo`).
PHOTO = 2
#: The stream of a component of a mix.
COMPONENT = 3
#: The stream of the mixing mask.
MASK = 4
_MASK64 = (1 << 64) - 1


def _splitmix64(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK64
    return x ^ (x >> 31)


def key(*parts: int) -> int:
    """A 63-bit seed from integers, the same in every process (unlike ``hash``)."""
    h = 0x5EED
    for p in parts:
        h = _splitmix64(h ^ _splitmix64(p & _MASK64))
    return h >> 1


class Stream:
    """The random draws of one part of a sample, from a ``torch.Generator`` of its own seeded with
    ``seed`` (a :func:`key`): scalars come back as Python floats and ints, and the same seed draws
    the same values in any process."""

    def __init__(self, seed: int):
        self.generator = torch.Generator().manual_seed(seed & 0xFFFF_FFFF_FFFF_FFFF)

    def uniform(self, low: float = 0.0, high: float = 1.0) -> float:
        u = float(torch.rand((), generator=self.generator, dtype=torch.float64))
        return low + (high - low) * u

    def log_uniform(self, low: float, high: float) -> float:
        return math.exp(self.uniform(math.log(low), math.log(high)))

    def chance(self, p: float) -> bool:
        return self.uniform() < p

    def integer(self, low: int, high: int) -> int:
        """An integer in ``[low, high]``."""
        return int(torch.randint(low, high + 1, (), generator=self.generator))

    def choice(self, options, weights=None):
        options = list(options)
        if weights is None:
            return options[self.integer(0, len(options) - 1)]
        u = self.uniform(0.0, float(sum(weights)))
        for option, w in zip(options, weights, strict=True):
            u -= w
            if u < 0:
                return option
        return options[-1]

    def angle(self) -> tuple[float, float]:
        """``(cos, sin)`` of a uniform angle."""
        a = self.uniform(0.0, 2 * math.pi)
        return math.cos(a), math.sin(a)

    def seed(self) -> int:
        return int(torch.randint(0, 2**62, (), generator=self.generator))
