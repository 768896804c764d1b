"""The prior term of a refinement: each map's L1 pull toward the maps it starts from.

``prior = sum_map w_map * mean | x - x_prior |`` on the maps' stored encodings (normal as
``(n + 1) / 2``), the term :class:`svbrdf_render.refinement.refine.RefineLoss` (one photo) and
:func:`svbrdf_render.refinement.views.refine_views` (several views) both add to their data term;
the weights are :attr:`svbrdf_render.RefineSettings.prior`.
"""

from __future__ import annotations

from collections.abc import Mapping

from torch import Tensor

from ..maps import MAP_NAMES, SVBRDF, stored_value

__all__ = ["prior_targets", "prior_weights", "with_prior"]


def prior_targets(prior: SVBRDF) -> dict[str, Tensor]:
    """The prior's maps on their stored encodings, computed once per refinement."""
    return {name: stored_value(name, t) for name, t in prior.maps().items()}


def prior_weights(settings) -> dict[str, float]:
    """Each map's prior weight of ``settings`` (a ``RefineSettings``; 0 for a map it does not name)."""
    weights: Mapping[str, float] = settings.prior
    return {name: float(weights.get(name, 0.0)) for name in MAP_NAMES}


def with_prior(loss: Tensor, maps: SVBRDF, targets: dict[str, Tensor], weights: dict[str, float]) -> Tensor:
    """``loss + sum_map w_map * mean |x - x_prior|`` (maps of zero weight left out)."""
    for name, t in maps.maps().items():
        if weights[name] > 0:
            loss = loss + weights[name] * (stored_value(name, t) - targets[name]).abs().mean()
    return loss
