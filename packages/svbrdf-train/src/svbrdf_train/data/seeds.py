"""Seeds of a procedural sample's random streams: the same integers in every process.

Sample ``index`` of data set ``seed`` draws each of its parts (its material, its photo, the
components of a mix, the mixing mask) from a :class:`~.procedural_noise.Draw` of its own,
seeded by :func:`key` of ``(seed, index, stream, ...)``: a part is drawn whatever the others
draw, and never from the global RNG, so a sample is the same in any process, worker and batch.
"""

from __future__ import annotations

__all__ = ["COMPONENT", "MASK", "MATERIAL", "PHOTO", "key"]

#: The streams of one sample: its material recipe, its photo, a component of a mix, the mixing mask.
MATERIAL, PHOTO, COMPONENT, MASK = 1, 2, 3, 4
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
