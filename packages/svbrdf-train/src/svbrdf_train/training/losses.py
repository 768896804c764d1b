"""The generator and discriminator losses of the paper (docs/svbrdf-train.md, "Recipes and losses").

::

    L_G = adv * L_adv + render * L_render + svbrdf * L_svbrdf        (0.1, 0.5, 0.5)

====================================  ================================================================
function                              what
====================================  ================================================================
:func:`map_loss`                      ``L_svbrdf``: weighted L1 per map (normal 1, diffuse 1,
                                      roughness 0.5, specular 0.5)
:func:`rendering_loss`                ``L_render``: L1 between log renderings of prediction and target
                                      under the same light/view configurations
:func:`discriminator_loss`            the discriminator's GAN objective on real and fake logits
:func:`generator_adversarial_loss`    ``L_adv``: the generator's GAN objective on fake logits
:func:`generator_loss`                ``L_G``, every term returned separately for logging
:class:`GanLoss`                      both objectives of a fit, built once from the recipe's
                                      ``loss`` section (``loss_of(recipe.loss)``)
====================================  ================================================================

GAN objectives (``kind``), both computed from logits:

- ``"bce"``: the paper's eq. 3, the standard GAN. The discriminator minimises
  ``-log D(real) - log(1 - D(fake))``; the generator the non-saturating ``-log D(fake)``,
  whose gradient stays near 1 where the discriminator rejects the fake with confidence
  (the saturating ``log(1 - D(fake))`` has a gradient ``sigmoid(logit)`` that vanishes there).
  Both use BCE-with-logits (a softplus), finite for any finite logit.
- ``"lsgan"``: least squares (Mao et al. 2017), targets 1 for real and 0 for fake:
  discriminator ``(D(real) - 1)^2 + D(fake)^2``, generator ``(D(fake) - 1)^2``, on the raw
  logits. Its gradient grows linearly with the logit.

The discriminator loss is the *sum* of its real and fake terms (eq. 3), not their mean as in
pix2pix; halve the discriminator's learning rate to get pix2pix's step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields

import torch
import torch.nn.functional as F
from torch import Tensor

from svbrdf_render import MAP_NAMES, SVBRDF, Scene, log_radiance, render

from ..recipe.paper_weights import MAP_WEIGHTS

__all__ = [
    "GAN_KINDS",
    "LossWeights",
    "map_loss",
    "rendering_loss",
    "discriminator_loss",
    "generator_adversarial_loss",
    "generator_loss",
    "GanLoss",
    "loss_of",
]

#: The GAN objectives :func:`discriminator_loss` and :func:`generator_adversarial_loss` know.
GAN_KINDS = ("bce", "lsgan")


# -- input checks ------------------------------------------------------------------------


def _check_weight(what: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what}: expected a number, got {type(value).__name__} {value!r}")
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"{what}: expected a finite weight >= 0, got {value!r}")


def _check_same_shape(fn: str, pred: SVBRDF, target: SVBRDF) -> None:
    for name, t in (("pred", pred), ("target", target)):
        if not isinstance(t, SVBRDF):
            raise ValueError(f"{fn}: {name} must be an SVBRDF, got {type(t).__name__}")
    if pred.shape != target.shape:
        raise ValueError(
            f"{fn}: pred and target must have the same (B, H, W); got {pred.shape} and {target.shape}"
        )


def _check_kind(fn: str, kind: str) -> None:
    if kind not in GAN_KINDS:
        raise ValueError(f"{fn}: unknown GAN kind {kind!r}; expected one of {', '.join(GAN_KINDS)}")


def _check_logits(fn: str, what: str, logits: Sequence[Tensor]) -> None:
    if isinstance(logits, Tensor):
        raise ValueError(f"{fn}: {what} must be a list of logit maps (B, 1, h, w), got a single tensor")
    if len(logits) == 0:
        raise ValueError(f"{fn}: {what} is empty; expected at least one logit map (B, 1, h, w)")
    for i, t in enumerate(logits):
        if not isinstance(t, Tensor) or not t.is_floating_point():
            got = t.dtype if isinstance(t, Tensor) else type(t).__name__
            raise ValueError(f"{fn}: {what}[{i}] must be a floating-point tensor, got {got}")


def _upcast(t: Tensor) -> Tensor:
    """float16/bfloat16 logits to float32: ``logit^2`` overflows float16 above ~256."""
    return t.float() if t.dtype in (torch.float16, torch.bfloat16) else t


# -- L_svbrdf ----------------------------------------------------------------------------


def map_loss(
    pred: SVBRDF, target: SVBRDF, weights: Mapping[str, float] = MAP_WEIGHTS
) -> tuple[Tensor, dict[str, Tensor]]:
    """``L_svbrdf = sum_m w_m * mean|pred_m - target_m|`` over the maps named in ``weights``.

    Args:
        pred: predicted maps, ``(B, C, H, W)`` each.
        target: ground-truth maps of the same ``(B, H, W)``.
        weights: map name -> weight ``>= 0``; the paper's :data:`MAP_WEIGHTS` by default.
            Maps not named are left out; a map with weight 0 still gets its L1 term (it is
            cheap and worth logging) but adds nothing to the total.

    Returns:
        ``(total, terms)``: the weighted sum (a 0-dim tensor) and ``{map name: mean L1}``,
        unweighted and still attached to the graph (log them with ``.item()``).

    Raises:
        ValueError: an unknown map name, a negative or non-finite weight, mismatched shapes.

    Example:
        >>> pred, target = SVBRDF.constant(1, 8), SVBRDF.constant(1, 8, roughness=0.7)
        >>> total, terms = map_loss(pred, target)
        >>> sorted(terms)
        ['diffuse', 'normal', 'roughness', 'specular']
    """
    _check_same_shape("map_loss", pred, target)
    for name, w in weights.items():
        if name not in MAP_NAMES:
            raise ValueError(
                f"map_loss: unknown map {name!r} in the map weights; expected some of {', '.join(MAP_NAMES)}"
            )
        _check_weight(f"map_loss: weight of {name!r}", w)
    if not weights:
        raise ValueError(f"map_loss: no map weights given; name some of {', '.join(MAP_NAMES)}")
    terms = {name: (getattr(pred, name) - getattr(target, name)).abs().mean() for name in weights}
    total = sum(weights[name] * term for name, term in terms.items())
    return total, terms


# -- L_render ----------------------------------------------------------------------------


def rendering_loss(
    pred: SVBRDF,
    target: SVBRDF,
    scene: Scene,
    eps: float = 0.01,
    backend: str = "eager",
    *,
    rendered: tuple[Tensor, Tensor] | None = None,
) -> Tensor:
    """``L_render = mean |log(R(pred) + eps) - log(R(target) + eps)|`` over the scene's configurations.

    Both map sets are rendered under the *same* scene, so configuration ``k`` of the
    prediction is compared with configuration ``k`` of the target (sample the scene once per
    step, e.g. with :func:`svbrdf_render.training_scene`, and pass it here). The target is
    data: it is rendered under ``torch.no_grad()`` and gets no gradient.

    Numerics: radiance goes through :func:`svbrdf_render.log_radiance` (clamped at 0 before
    the log), so black renderings give ``log(eps)`` and the gradient per rendered value is at
    most ``1 / eps``.

    Args:
        pred: predicted maps, ``(B, C, H, W)`` each.
        target: ground-truth maps of the same ``(B, H, W)``.
        scene: ``K`` light/view configurations (configuration shape ``()``, ``(K,)`` or ``(B, K)``).
        eps: the offset inside the log, ``> 0``.
        backend: the renderer backend, ``"eager"`` or ``"compiled"``.
        rendered: ``(render(pred, scene), render(target, scene))`` when the caller has them
            already (the trainer renders once for this loss and the discriminator); then
            ``scene`` and ``backend`` are not used.

    Returns:
        A 0-dim tensor: the mean over ``(B, K, 3, H, W)``.
    """
    _check_same_shape("rendering_loss", pred, target)
    if rendered is not None:
        fake, real = rendered
        if fake.shape != real.shape or fake.shape[0] != pred.batch_size:
            raise ValueError(
                f"rendering_loss: rendered must be two (B, K, 3, H, W) tensors of pred's batch; got "
                f"{tuple(fake.shape)} and {tuple(real.shape)}"
            )
        real = real.detach()
    else:
        fake = render(pred, scene, backend=backend)
        with torch.no_grad():
            real = render(target, scene, backend=backend)
    return (log_radiance(fake, eps) - log_radiance(real, eps)).abs().mean()


# -- L_adv -------------------------------------------------------------------------------


def discriminator_loss(real_logits: list[Tensor], fake_logits: list[Tensor], kind: str = "bce") -> Tensor:
    """The discriminator's GAN loss: real judged real, fake judged fake.

    ``"bce"``: ``softplus(-real) + softplus(fake)`` = ``-log D(real) - log(1 - D(fake))``.
    ``"lsgan"``: ``(real - 1)^2 + fake^2``. Each term is the mean over a logit map; the loss
    is the mean over the list (one map per discriminator head, e.g. one per SVBRDF map).

    Args:
        real_logits: ``[(B, 1, h, w), ...]``, the discriminator on ground truth.
        fake_logits: as many maps, the discriminator on (detached) predictions.
        kind: one of :data:`GAN_KINDS`.

    Returns:
        A 0-dim tensor. With all logits 0: ``2 log 2`` (``"bce"``) or ``1`` (``"lsgan"``).
    """
    _check_kind("discriminator_loss", kind)
    _check_logits("discriminator_loss", "real_logits", real_logits)
    _check_logits("discriminator_loss", "fake_logits", fake_logits)
    if len(real_logits) != len(fake_logits):
        raise ValueError(
            f"discriminator_loss: {len(real_logits)} real and {len(fake_logits)} fake logit maps; "
            "expected one of each per discriminator head"
        )
    losses = []
    for real, fake in zip(real_logits, fake_logits, strict=True):
        real, fake = _upcast(real), _upcast(fake)
        if kind == "bce":
            r = F.binary_cross_entropy_with_logits(real, torch.ones_like(real))
            f = F.binary_cross_entropy_with_logits(fake, torch.zeros_like(fake))
        else:
            r = (real - 1).square().mean()
            f = fake.square().mean()
        losses.append(r + f)
    return torch.stack(losses).mean()


def generator_adversarial_loss(fake_logits: list[Tensor], kind: str = "bce") -> Tensor:
    """``L_adv``: the generator's GAN loss, fake judged real.

    ``"bce"``: the non-saturating ``-log D(fake)`` = ``softplus(-fake)``; its gradient
    ``-(1 - sigmoid(fake))`` is about -1 where the discriminator is sure the fake is fake
    (very negative logits), where the saturating ``log(1 - D(fake))`` would give ~0.
    ``"lsgan"``: ``(fake - 1)^2``. Mean over each logit map, then over the list.

    Args:
        fake_logits: ``[(B, 1, h, w), ...]``, the discriminator on the prediction (not detached).
        kind: one of :data:`GAN_KINDS`.

    Returns:
        A 0-dim tensor. With all logits 0: ``log 2`` (``"bce"``) or ``1`` (``"lsgan"``).
    """
    _check_kind("generator_adversarial_loss", kind)
    _check_logits("generator_adversarial_loss", "fake_logits", fake_logits)
    losses = []
    for fake in fake_logits:
        fake = _upcast(fake)
        if kind == "bce":
            losses.append(F.binary_cross_entropy_with_logits(fake, torch.ones_like(fake)))
        else:
            losses.append((fake - 1).square().mean())
    return torch.stack(losses).mean()


# -- L_G ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class LossWeights:
    """The weights of the generator loss terms (the paper's lambda_1..3). Set one to 0 to ablate it."""

    adv: float = 0.1
    """lambda_1: weight of the adversarial loss L_adv (0: no discriminator)."""
    render: float = 0.5
    """lambda_2: weight of the log rendering loss L_render (0: no rendering)."""
    svbrdf: float = 0.5
    """lambda_3: weight of the per-map L1 loss L_svbrdf."""

    def __post_init__(self):
        for f in fields(self):
            _check_weight(f"LossWeights.{f.name}", getattr(self, f.name))
        if self.adv == 0 and self.render == 0 and self.svbrdf == 0:
            raise ValueError("LossWeights: every weight is 0, so there is nothing to train; set one > 0")


def generator_loss(
    pred: SVBRDF,
    target: SVBRDF,
    *,
    scene: Scene | None = None,
    weights: LossWeights = LossWeights(),  # noqa: B008 - frozen, so safe to share
    map_weights: Mapping[str, float] = MAP_WEIGHTS,
    fake_logits: list[Tensor] | None = None,
    gan: str = "bce",
    eps: float = 0.01,
    backend: str = "eager",
    rendered: tuple[Tensor, Tensor] | None = None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """``L_G = adv * L_adv + render * L_render + svbrdf * L_svbrdf``, with every term for logging.

    A term whose weight is 0 is *not computed*: with ``adv == 0`` no logits are needed (the
    discriminator need not run), with ``render == 0`` nothing is rendered and ``scene`` is
    not needed, with ``svbrdf == 0`` the maps are not compared. Such a term is absent from
    the returned dict.

    Args:
        pred: predicted maps, ``(B, C, H, W)`` each.
        target: ground-truth maps of the same ``(B, H, W)``.
        scene: the light/view configurations of the rendering loss; required iff ``render > 0``.
        weights: the term weights (the paper's 0.1, 0.5, 0.5 by default).
        map_weights: the per-map weights of ``L_svbrdf`` (:func:`map_loss`).
        fake_logits: the discriminator's logit maps on ``pred`` (graph attached to ``pred``);
            required iff ``adv > 0``.
        gan: the GAN objective, one of :data:`GAN_KINDS`.
        eps: the offset inside the log of the rendering loss.
        backend: the renderer backend of the rendering loss.
        rendered: ``(render(pred, scene), render(target, scene))`` if already computed
            (see :func:`rendering_loss`); saves rendering the prediction twice.

    Returns:
        ``(total, terms)``: ``total`` is ``L_G``; ``terms`` holds the *unweighted* terms
        ``"adv"``, ``"render"``, ``"svbrdf"``, ``"map/<name>"`` of those computed, and
        ``"total"``; every value is a 0-dim tensor still attached to the graph.
    """
    _check_generator_inputs(weights, gan, fake_logits, scene, rendered)
    terms = _generator_terms(
        pred, target, scene, weights, map_weights, fake_logits, gan, eps, backend, rendered
    )
    total = _weighted_total(terms, weights)
    terms["total"] = total
    return total, terms


def _check_generator_inputs(
    weights: LossWeights,
    gan: str,
    fake_logits: list[Tensor] | None,
    scene: Scene | None,
    rendered: tuple[Tensor, Tensor] | None,
) -> None:
    """What :func:`generator_loss` needs for the terms its weights ask for, and nothing more."""
    if not isinstance(weights, LossWeights):
        raise ValueError(f"generator_loss: weights must be a LossWeights, got {type(weights).__name__}")
    _check_kind("generator_loss", gan)
    if weights.adv > 0 and fake_logits is None:
        raise ValueError(
            f"generator_loss: the adversarial weight is {weights.adv}, so fake_logits (the discriminator's "
            "logits on pred) are required; pass them, or set LossWeights(adv=0) to train without L_adv"
        )
    if weights.adv == 0 and fake_logits is not None:
        raise ValueError(
            "generator_loss: fake_logits given but the adversarial weight is 0; "
            "do not run the discriminator, or set LossWeights(adv=...) > 0"
        )
    if weights.render > 0 and scene is None and rendered is None:
        raise ValueError(
            f"generator_loss: the rendering weight is {weights.render}, so a scene is required "
            "(e.g. svbrdf_render.training_scene(batch)); or set LossWeights(render=0)"
        )


def _generator_terms(
    pred: SVBRDF,
    target: SVBRDF,
    scene: Scene | None,
    weights: LossWeights,
    map_weights: Mapping[str, float],
    fake_logits: list[Tensor] | None,
    gan: str,
    eps: float,
    backend: str,
    rendered: tuple[Tensor, Tensor] | None,
) -> dict[str, Tensor]:
    """The unweighted terms of ``L_G`` whose weight is not 0: ``adv``, ``render``, ``svbrdf`` and
    its ``map/<name>``, in that order."""
    terms: dict[str, Tensor] = {}
    if weights.adv > 0:
        terms["adv"] = generator_adversarial_loss(fake_logits, gan)
    if weights.render > 0:
        terms["render"] = rendering_loss(pred, target, scene, eps=eps, backend=backend, rendered=rendered)
    if weights.svbrdf > 0:
        terms["svbrdf"], per_map = map_loss(pred, target, map_weights)
        terms.update({f"map/{name}": value for name, value in per_map.items()})
    return terms


def _weighted_total(terms: Mapping[str, Tensor], weights: LossWeights) -> Tensor:
    """``adv * L_adv + render * L_render + svbrdf * L_svbrdf`` over the terms computed, summed in
    that order."""
    total = None
    for name in ("adv", "render", "svbrdf"):
        if name in terms:
            part = getattr(weights, name) * terms[name]
            total = part if total is None else total + part
    return total


# -- the objectives of a fit ---------------------------------------------------------------


@dataclass(frozen=True)
class GanLoss:
    """The generator's and the discriminator's objectives of one fit, with their settings.

    The recipe's ``loss`` section describes it (``loss_of(recipe.loss)`` builds it). Calling it gives
    :func:`generator_loss` with these weights; :meth:`discriminator` gives
    :func:`discriminator_loss`; :meth:`looks` is what the discriminator sees of renderings,
    ``log(R + eps)``, as the rendering loss compares them.
    """

    weights: LossWeights
    map_weights: Mapping[str, float]
    gan: str = "bce"
    eps: float = 0.01

    def __call__(
        self,
        pred: SVBRDF,
        target: SVBRDF,
        *,
        fake_logits: list[Tensor] | None = None,
        rendered: tuple[Tensor, Tensor] | None = None,
        scene: Scene | None = None,
        backend: str = "eager",
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """``(L_G, terms)`` of :func:`generator_loss` (its arguments, less the settings)."""
        return generator_loss(
            pred,
            target,
            scene=scene,
            weights=self.weights,
            map_weights=self.map_weights,
            fake_logits=fake_logits,
            gan=self.gan,
            eps=self.eps,
            backend=backend,
            rendered=rendered,
        )

    def discriminator(self, real_logits: list[Tensor], fake_logits: list[Tensor]) -> Tensor:
        """The discriminator's loss (:func:`discriminator_loss`) of this fit's ``gan`` kind."""
        return discriminator_loss(real_logits, fake_logits, self.gan)

    def looks(self, renderings: Tensor) -> Tensor:
        """What the discriminator sees of ``renderings``: ``log(R + eps)``."""
        return log_radiance(renderings, self.eps)


def loss_of(section) -> GanLoss:
    """The objectives the recipe's ``loss`` section describes: the generator's ``L_G`` with its
    weights and the discriminator's, both of its ``gan`` kind."""
    weights = LossWeights(adv=section.adv, render=section.render, svbrdf=section.svbrdf)
    return GanLoss(weights=weights, map_weights=section.maps, gan=section.gan, eps=section.eps)
