"""Deprecated: the photo tool lives in svbrdf-models (:mod:`svbrdf_models.capture`: it needs
no training code). This module names the same objects for one more release, with a
``DeprecationWarning``; import them from ``svbrdf_models.capture`` (see CHANGELOG.md)."""

from __future__ import annotations

import warnings

from svbrdf_models.capture import *  # noqa: F403 - the same objects, not copies
from svbrdf_models.capture import __all__  # noqa: F401

warnings.warn(
    "svbrdf_train.capture is deprecated and goes in the next release: import the same names from "
    "svbrdf_models.capture",
    DeprecationWarning,
    stacklevel=2,
)
