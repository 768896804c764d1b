"""The ranges every recipe section shares: sizes, seeds, resolutions, and the one-line checks
that refuse a value out of range naming its field."""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable
from typing import Any

__all__ = ["SIZES", "MAX_SEED", "MIN_RESOLUTION", "MAX_RESOLUTION", "MAX_SAMPLES", "suggest"]

#: Sizes every built-in recipe has: the paper's, one for a CPU in minutes, one for tests.
SIZES = ("paper", "cpu", "smoke")
#: Seeds are drawn from [0, MAX_SEED] (numpy's SeedSequence refuses negative ones).
MAX_SEED = 2**32 - 1
#: The smallest training size in pixels: below it, no network has a layer left.
MIN_RESOLUTION = 8
#: The largest training size in pixels: above it, no GPU holds a batch.
MAX_RESOLUTION = 8192
#: Samples per epoch and held out for validation (``data.count``, ``data.validation``, a mix
#: entry's): 10**8, 500 times the paper's 200k. Each epoch's shuffle holds one 8-byte index per
#: sample (800 MB at this bound); 10**12 asked torch for 8 TB and failed deep in the fit.
MAX_SAMPLES = 10**8


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check(ok: bool, field: str, value: Any, expected: str) -> None:
    """ValueError ``"field must be expected, got value"`` unless ``ok``."""
    if not ok:
        raise ValueError(f"{field} must be {expected}, got {value!r}")


def _finite(value: Any, field: str, *, low: float = 0.0, positive: bool = False) -> None:
    ok = _number(value) and math.isfinite(value) and (value > low if positive else value >= low)
    _check(ok, field, value, f"a finite number {'>' if positive else '>='} {low:g}")


def _int_at_least(value: Any, field: str, low: int, *, none: str | None = None) -> None:
    if value is None and none is not None:
        return
    expected = f"at least {low}" + (f" (or null: {none})" if none else "")
    _check(value is not None and value >= low, field, value, expected)


def _samples(value: Any, field: str, low: int) -> None:
    """A sample count in ``[low, MAX_SAMPLES]``."""
    _int_at_least(value, field, low)
    _check(value <= MAX_SAMPLES, field, value, f"at most {MAX_SAMPLES:_} samples")


def _seed(value: int, field: str) -> None:
    _check(0 <= value <= MAX_SEED, field, value, f"in [0, {MAX_SEED}] (2**32 - 1)")


def suggest(key: str, options: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the option closest to a mistyped ``key``, else ``""``."""
    close = difflib.get_close_matches(key, list(options), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""
