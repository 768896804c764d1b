"""Recipes by name: the entry-point group ``svbrdf.recipes``, where each entry names a YAML file.

svbrdf-train registers its own recipes that way (``svbrdf_train.recipes``); a plugin adds one
by naming its file in the same group. A name registered twice, or an entry that fails to
load, is refused naming the distributions.
"""

from __future__ import annotations

import difflib
import importlib.metadata
from pathlib import Path
from typing import Any

from ..errors import RecipeError

__all__ = ["RECIPE_GROUP", "list_recipes", "recipe_path"]

RECIPE_GROUP = "svbrdf.recipes"


def _entry_points() -> dict[str, list[Any]]:
    found: dict[str, list[Any]] = {}
    for ep in importlib.metadata.entry_points(group=RECIPE_GROUP):
        same = found.setdefault(ep.name, [])
        if not any(e.value == ep.value for e in same):
            same.append(ep)
    return found


def list_recipes() -> list[str]:
    """Names of the registered recipes (built-ins and plugins), sorted."""
    return sorted(_entry_points())


def recipe_path(name_or_path: str | Path) -> Path:
    """The YAML file of a registered recipe name, or the given path if it is a file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.is_file():
        if not p.is_file():
            raise RecipeError(f"{p}: recipe file not found")
        return p
    eps = _entry_points()
    entries = eps.get(str(name_or_path))
    if not entries:
        close = difflib.get_close_matches(str(name_or_path), list(eps), n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
        raise RecipeError(
            f"unknown recipe {str(name_or_path)!r}.{hint} Recipes: {', '.join(sorted(eps)) or 'none'}; "
            "or give the path of a YAML file."
        )
    if len(entries) > 1:
        who = " and ".join(f"{e.dist.name if e.dist else '?'} ({e.value})" for e in entries)
        raise RecipeError(f"recipe {name_or_path!r} is registered by {who}; uninstall or rename one")
    try:
        target = entries[0].load()
    except Exception as e:  # a plugin can fail in any way on import
        raise RecipeError(f"recipe {name_or_path!r} ({entries[0].value}) failed to load: {e}") from e
    return Path(target)
