"""Optional dependencies of the ``io`` extra, imported on first use."""

from __future__ import annotations

import importlib
from types import ModuleType


def require(module: str, distribution: str, purpose: str) -> ModuleType:
    """Import ``module`` or raise an ImportError that says how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"{purpose} needs {distribution}: pip install 'svbrdf-render[io]'"
        ) from None
