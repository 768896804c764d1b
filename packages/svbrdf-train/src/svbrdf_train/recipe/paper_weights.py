"""The paper's per-map weights of its L1 map loss ``L_svbrdf``, written once: normal and
diffuse albedo weigh 1, roughness and specular albedo 0.5. The loss
(:data:`svbrdf_train.training.losses.MAP_WEIGHTS`) and the recipe schema's default (``loss.maps``) both
read them from here, in the recipe room that the trainer imports (never the other way); this module imports nothing heavy, so recipes stay quick to load."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["MAP_WEIGHTS"]

#: map name -> weight in ``L_svbrdf`` (read-only).
MAP_WEIGHTS: Mapping[str, float] = MappingProxyType(
    {"normal": 1.0, "diffuse": 1.0, "roughness": 0.5, "specular": 0.5}
)
