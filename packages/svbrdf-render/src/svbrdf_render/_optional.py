"""Optional dependencies (the ``io`` and ``exr`` extras), imported on first use."""

from __future__ import annotations

import importlib
from types import ModuleType


def require(module: str, distribution: str, purpose: str, extra: str = "io") -> ModuleType:
    """Import ``module`` or raise an ImportError that says how to install it (``extra``: the
    package extra that pulls ``distribution``)."""
    try:
        return importlib.import_module(module)
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"{purpose} needs {distribution}: pip install 'svbrdf-render[{extra}]'"
        ) from None
