"""YAML as people write it: ``3e-4`` is a number.

PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent: ``3e-4``,
``1e5`` and ``1.5e3`` come back as strings, so a file that says ``lr: 3e-4`` is refused
while ``--set optim.lr=3e-4`` is not. :func:`safe_load` is ``yaml.safe_load`` with YAML
1.2's float syntax added; everything else (ints, bools, nulls, dates) reads as before.
Scene files (svbrdf-render) and recipe files and ``--set`` values (svbrdf-train) are all
read with it.
"""

from __future__ import annotations

import re
from typing import Any

from ._optional import require

__all__ = ["safe_load", "loader"]

#: YAML 1.2 floats that 1.1 reads as strings: no dot (``3e-4``, ``1e5``), an unsigned
#: exponent (``1.5e3``), a signed leading dot (``-.5``). Tried after YAML 1.1's own
#: resolvers, so ``4`` stays an int and ``2024-01-01`` a date.
_FLOAT = re.compile(
    r"""^[-+]?(?:(?:\.[0-9_]+|[0-9][0-9_]*\.[0-9_]*)(?:[eE][-+]?[0-9]+)?|[0-9][0-9_]*[eE][-+]?[0-9]+)$""",
)

_LOADER = None


def loader():
    """The ``yaml.SafeLoader`` subclass that :func:`safe_load` uses."""
    global _LOADER
    if _LOADER is None:
        yaml = require("yaml", "PyYAML", "reading YAML")

        class Loader(yaml.SafeLoader):
            """SafeLoader that also reads ``3e-4`` and ``1e5`` as floats (YAML 1.2)."""

        Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))
        _LOADER = Loader
    return _LOADER


def safe_load(text: str) -> Any:
    """``yaml.safe_load(text)``, with ``3e-4`` read as the number; raises ``yaml.YAMLError``."""
    yaml = require("yaml", "PyYAML", "reading YAML")
    return yaml.load(text, Loader=loader())  # noqa: S506 - a SafeLoader subclass
