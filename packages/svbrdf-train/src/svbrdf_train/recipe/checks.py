"""Settings of a recipe that are each in range but cannot work together, refused at once.

:func:`check_recipe` asks svbrdf-models whether the networks exist and which input sizes they
take (nothing is built), and compares sections with each other (a discriminator that judges
another number of renderings than the loss draws, fewer samples an epoch than a batch, ...),
so that nothing fails later in the first step. A recipe it passed is marked
(:attr:`Recipe.checked <svbrdf_train.recipe.schema.Recipe.checked>`): a fit checks only a
recipe that is not.
"""

from __future__ import annotations

from typing import Any

from svbrdf_models import RegistryError, resolve_config

from ..errors import RecipeError
from .schema import Recipe

__all__ = ["check_recipe", "show"]


def show(value: Any) -> str:
    """A value as a user writes it in YAML or ``--set`` (``null`` for None)."""
    return "null" if value is None else str(value)


def check_recipe(recipe: Recipe, where: str) -> None:
    """Refuse settings of ``recipe`` that are each in range but cannot work together.

    The networks are checked through svbrdf-models' own config validation (names, presets,
    fields, the attention modules a generator names) and asked which input sizes they take;
    nothing is built. A recipe that passes is marked checked (``recipe.checked``).

    Raises:
        RecipeError: starting with ``where`` and naming the fields.
    """
    from svbrdf_models import check_input_size

    t, d = recipe.train, recipe.data  # None only in a damaged checkpoint's recipe
    if recipe.loss is not None and recipe.loss.adv > 0 and recipe.discriminator is None:
        raise RecipeError(
            f"{where}: loss.adv is {recipe.loss.adv} but no discriminator is set; set one or loss.adv=0"
        )
    for kind, section in (("generator", recipe.generator), ("discriminator", recipe.discriminator)):
        if section is None:
            continue
        try:
            config = resolve_config(kind, section.name, section.config)
        except RegistryError as e:
            raise RecipeError(f"{where}: {kind}: {e}") from None
        if t is None:
            continue
        try:
            check_input_size(kind, section.name, section.config, t.resolution)
        except RegistryError as e:
            raise RecipeError(
                f"{where}: train.resolution is {t.resolution}, but {e}; set train.resolution to a size "
                f"the {kind} takes, or change {kind}.config"
            ) from None
        wants = getattr(config, "renderings", None) if kind == "discriminator" else None
        if wants is not None and wants != t.renderings:
            raise RecipeError(
                f"{where}: discriminator.config.renderings is {wants} but train.renderings is "
                f"{t.renderings}; the discriminator judges the renderings the loss draws: set both alike"
            )
    if t is not None and d is not None and (t.keep_best or "").startswith("val_fold/") and not _has_fold(d):
        raise RecipeError(
            f"{where}: train.keep_best is {t.keep_best} but no materials source holds out a fold "
            "(data.fold, or a materials entry's fold in data.mix); give one a fold (e.g. 1/5) or "
            "choose on val/rmse/render"
        )
    if d is not None and d.source == "procedural" and d.path is not None:
        raise RecipeError(
            f"{where}: data.path is {show(d.path)} but data.source is 'procedural', which reads no files; "
            "set data.source to shards or des18 (fit --data PATH does both), or data.path=null"
        )
    if t is not None and d is not None and d.source in ("procedural", "mix") and d.count < t.batch:
        raise RecipeError(
            f"{where}: data.count is {d.count}, fewer samples per epoch than one step of train.batch "
            f"{t.batch}; raise data.count or lower train.batch"
        )
    object.__setattr__(recipe, "_checked", True)  # frozen: the mark is no field (module doc)


def _has_fold(d) -> bool:
    """Whether a materials source of data section ``d`` holds out a fold (``val_fold/``)."""
    entries = list(d.mix or ()) if d.source == "mix" else [{"source": d.source, "fold": d.fold}]
    return any(e.get("source") == "materials" and e.get("fold") for e in entries)
