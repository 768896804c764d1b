"""Capture: from a real flash photo to maps. The photo tool lives in svbrdf-models
(:mod:`svbrdf_models.capture`: it needs no training code); this module names the same objects
for callers of ``svbrdf_train.capture``, by the list that module exports."""

from __future__ import annotations

from svbrdf_models.capture import *  # noqa: F403 - the same objects, not copies
from svbrdf_models.capture import __all__  # noqa: F401
