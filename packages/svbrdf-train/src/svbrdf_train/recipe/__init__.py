"""Recipes: named, complete training configurations, read from YAML.

A recipe file holds the sections below; a recipe may start from another (``base: ours``, or
the path of a YAML file, read from the recipe's own folder when relative) and change only
what differs, and lists ``sizes``: dotted overrides that turn the paper's configuration into
ones that finish in minutes on a CPU::

    description: the paper's model
    generator: {name: ours, config: {}}
    discriminator: {name: patchgan, config: {renderings: 9}}
    loss: {adv: 0.1, render: 0.5, svbrdf: 0.5}
    sizes:
      cpu: {generator.config.preset: small, train.resolution: 128}

Recipes are found by name through the entry-point group ``svbrdf.recipes`` (each entry
names a YAML file path; svbrdf-train registers its own that way), or given as a path. Any
field can be overridden with ``--set section.field=value`` (the value is read as YAML;
files and values alike read ``3e-4`` as a number, see :mod:`svbrdf_render.formats.yamlio`).
Unknown sections and fields are errors naming the field and the file.

=====================================  ==========================================================
module                                 what it owns
=====================================  ==========================================================
:mod:`~svbrdf_train.recipe.schema`     the sections, their fields and ranges, and what each
                                       builds (``optim.setup``, ``loss.setup``, ``data.setup``)
:mod:`~svbrdf_train.recipe.checks`     settings that cannot work together (:func:`check_recipe`)
:mod:`~svbrdf_train.recipe.files`      YAML files, bases, sizes, ``--set``, plain data, diffs
:mod:`~svbrdf_train.recipe.registry`   recipes by name (the ``svbrdf.recipes`` entry points)
=====================================  ==========================================================

Every public name is importable from here.
"""

from .checks import check_recipe
from .files import (
    RecipeFile,
    load_recipe,
    parse_overrides,
    read_recipe,
    recipe_differences,
    recipe_from_dict,
    with_overrides,
)
from .registry import RECIPE_GROUP, list_recipes, recipe_path
from .datasection import BALANCES, CAPTURES, MIX_KEYS, MIX_SOURCES, DataSection
from .schema import KEEP_BEST_METRICS, LossSection, NetworkSection, OptimSection, Recipe, TrainSection
from .values import MAX_RESOLUTION, MAX_SEED, MIN_RESOLUTION, SIZES

__all__ = [
    "SIZES",
    "MAX_SEED",
    "MIN_RESOLUTION",
    "MAX_RESOLUTION",
    "RECIPE_GROUP",
    "CAPTURES",
    "BALANCES",
    "KEEP_BEST_METRICS",
    "NetworkSection",
    "LossSection",
    "OptimSection",
    "DataSection",
    "MIX_KEYS",
    "MIX_SOURCES",
    "TrainSection",
    "Recipe",
    "RecipeFile",
    "list_recipes",
    "recipe_path",
    "read_recipe",
    "load_recipe",
    "parse_overrides",
    "recipe_from_dict",
    "check_recipe",
    "recipe_differences",
    "with_overrides",
]
