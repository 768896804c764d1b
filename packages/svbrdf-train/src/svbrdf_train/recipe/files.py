"""Recipe files: YAML with bases and sizes, ``--set`` overrides, recipes as plain data, diffs.

A recipe file may start from another (``base: ours``, or the path of a YAML file, read from
the recipe's own folder when relative) and change only what differs; its ``sizes`` are dotted
overrides (``train.resolution: 128``) that turn the paper's configuration into smaller ones.
:func:`read_recipe` reads a file and its bases once into a :class:`RecipeFile`;
:meth:`RecipeFile.recipe` applies a size and overrides and checks the result
(:func:`load_recipe` does both). :func:`recipe_from_dict` reads back what
:meth:`Recipe.to_dict` wrote (a checkpoint's recipe), :func:`with_overrides` applies
``--set`` overrides to a recipe, and :func:`recipe_differences` lists the fields two recipes
differ in.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from svbrdf_models import ConfigError, build_config
from svbrdf_render.formats.yamlio import safe_load

from ..errors import RecipeError
from .checks import check_recipe, show
from .registry import recipe_path
from .schema import SECTIONS, TOP_LEVEL, Recipe
from .values import suggest

__all__ = [
    "RecipeFile",
    "read_recipe",
    "load_recipe",
    "parse_overrides",
    "recipe_from_dict",
    "recipe_differences",
    "with_overrides",
]


def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml

    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise RecipeError(
            f"{path}: not UTF-8 text (byte {e.object[e.start]:#04x} at offset {e.start}); "
            "save the recipe as UTF-8"
        ) from None
    except OSError as e:
        raise RecipeError(f"{path}: cannot read the recipe ({e.strerror})") from None
    try:
        # lr: 3e-4 is a number, as with --set; duplicate keys, deep nesting and alias bombs
        # are refused here, before anything walks the document (svbrdf_render.formats.yamlio)
        data = safe_load(text)
    except yaml.YAMLError as e:
        raise RecipeError(f"{path}: not valid YAML: {e}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise RecipeError(f"{path}: a recipe is a mapping of sections, got {type(data).__name__}")
    unknown = set(data) - TOP_LEVEL
    if unknown:
        key = sorted(unknown)[0]
        raise RecipeError(
            f"{path}: unknown section {key!r}{suggest(key, TOP_LEVEL)}; "
            f"sections: {', '.join(sorted(TOP_LEVEL))}"
        )
    return data


def _merge(base: dict[str, Any], top: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in top.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) and k != "config":
            out[k] = _merge(dict(out[k]), v)
        else:
            out[k] = v
    return out


def _resolve_file(path: Path, seen: tuple[Path, ...] = ()) -> tuple[dict[str, Any], dict[str, dict]]:
    """The merged sections of a recipe file and its bases, and its sizes (bases' sizes too)."""
    if path.resolve() in seen:
        chain = " -> ".join(str(p) for p in (*seen, path))
        raise RecipeError(f"{path}: recipes base on each other in a loop: {chain}")
    data = _read_yaml(path)
    sections: dict[str, Any] = {}
    sizes: dict[str, dict] = {}
    if "base" in data:
        base_path = _base_path(data["base"], path)
        sections, sizes = _resolve_file(base_path, (*seen, path.resolve()))
    own = {k: v for k, v in data.items() if k not in ("base", "sizes")}
    sections = _merge(sections, own)
    if not isinstance(data.get("sizes") or {}, Mapping):
        raise RecipeError(f"{path}: sizes must map size names to overrides, got {data['sizes']!r:.80}")
    for size, overrides in (data.get("sizes") or {}).items():
        if not isinstance(overrides, Mapping):
            raise RecipeError(f"{path}: sizes.{size} must map dotted fields to values")
        sizes[size] = {**sizes.get(size, {}), **overrides}
    return sections, sizes


def _base_path(base: Any, path: Path) -> Path:
    """The file ``base:`` names in recipe ``path``: a relative path is read from the recipe's own
    folder (wherever the command runs), a bare name is a registered recipe."""
    if not isinstance(base, str) or not base.strip():
        raise RecipeError(f"{path}: base: expected a recipe name or the path of a YAML file, got {base!r}")
    p = Path(base).expanduser()
    if not p.is_absolute():
        beside = path.parent / p
        if beside.suffix in (".yaml", ".yml") or beside.is_file():
            if not beside.is_file():
                raise RecipeError(
                    f"{path}: base: {base!r}: no file {beside} (a relative base is read from the "
                    "folder of the recipe that names it)"
                )
            return beside
    try:
        return recipe_path(p if p.is_absolute() else base)
    except RecipeError as e:
        raise RecipeError(f"{path}: base: {e}") from None


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["loss.adv=0", "train.batch=4"]`` -> ``{"loss.adv": 0, "train.batch": 4}``; values are YAML."""
    import yaml

    out: dict[str, Any] = {}
    given: dict[str, str] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or "." not in key:
            raise RecipeError(f"--set {item!r}: expected section.field=value, e.g. --set loss.adv=0")
        key = key.strip()
        if key in given:  # the last one would win without a word
            raise RecipeError(
                f"--set {key} is given twice ({given[key]!r} and {item!r}); give each field once"
            )
        given[key] = item
        try:
            value = safe_load(raw)  # read as recipe files are: 3e-4 is a number
        except yaml.YAMLError as e:
            raise RecipeError(f"--set {item!r}: the value is not valid YAML: {e}") from None
        out[key] = value
    return out


def _apply(
    sections: dict[str, Any], overrides: Mapping[str, Any], where: str, *, skip_disabled: bool = False
) -> dict[str, Any]:
    """Dotted ``overrides`` applied to ``sections``. With ``skip_disabled`` (sizes), a section the
    recipe set to null (``discriminator: null``) stays off instead of being re-created."""
    sections = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in sections.items()}
    for dotted, value in overrides.items():
        section, _, rest = dotted.partition(".")
        if section not in SECTIONS:
            raise RecipeError(f"{where}: {dotted!r}: unknown section {section!r}{suggest(section, SECTIONS)}")
        cls = SECTIONS[section]
        field, _, sub = rest.partition(".")
        names = [f.name for f in dataclasses.fields(cls)]
        if field not in names:
            raise RecipeError(
                f"{where}: {dotted!r}: unknown field {field!r} of section {section!r}"
                f"{suggest(field, names)}; "
                f"fields: {', '.join(names)}"
            )
        if section in sections and sections[section] is None:
            if skip_disabled:
                continue
            sections[section] = {}
        target = sections.setdefault(section, {})
        if sub:  # into a dict field, e.g. generator.config.preset or loss.maps.normal
            inner = dict(target.get(field) or {})
            node = inner
            keys = sub.split(".")
            for k in keys[:-1]:
                node = node.setdefault(k, {})
            node[keys[-1]] = value
            target[field] = inner
        else:
            target[field] = value
    return sections


@dataclass(frozen=True)
class RecipeFile:
    """A recipe file read with its bases: its sections (merged) and its sizes (bases' too)."""

    path: Path
    name: str
    sections: dict[str, Any]
    sizes: dict[str, dict]

    def settings(self, size: str = "paper", overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The sections at ``size`` with dotted ``overrides`` applied, as plain data (unchecked)."""
        self._known(size)
        sections = self.sections
        if size != "paper":
            where = f"{self.path} (sizes.{size})"
            sections = _apply(sections, self.sizes[size], where, skip_disabled=True)
        if overrides:
            sections = _apply(sections, overrides, f"--set (recipe {self.path})")
        return sections

    def recipe(self, size: str = "paper", overrides: Mapping[str, Any] | None = None) -> Recipe:
        """The checked recipe at ``size`` with ``overrides`` (:func:`load_recipe` says how)."""
        self._known(size)
        for other in ("paper", *self.sizes):
            if other != size:
                self._sized(other)
        recipe = self._sized(size)
        if overrides:
            recipe = self._sized(size, overrides)
        return recipe

    def _known(self, size: str) -> None:
        if size != "paper" and size not in self.sizes:
            raise RecipeError(
                f"{self.path}: no size {size!r}{suggest(size, self.sizes)}; "
                f"sizes: paper, {', '.join(self.sizes) or '(none)'}"
            )

    def _sized(self, size: str, overrides: Mapping[str, Any] | None = None) -> Recipe:
        """The recipe at ``size`` with ``overrides``, checked; errors say which."""
        where = f"{self.path} (size {size})"
        if overrides:
            given = ", ".join(f"{k}={show(v)}" for k, v in overrides.items())
            where = f"{where} with {given}"
        sections = self.settings(size, overrides)
        recipe = _build(sections, where, name=self.name, size=size, source=str(self.path))
        check_recipe(recipe, where)
        return recipe


def _build(sections: Mapping[str, Any], where: str, *, name: str, size: str, source: str) -> Recipe:
    """The :class:`Recipe` of a file's ``sections`` (missing ones at their defaults), unchecked."""

    def build(section: str):
        values = sections.get(section)
        if values is None:
            return SECTIONS[section]()  # at its defaults
        if not isinstance(values, Mapping):
            raise RecipeError(f"{where}: section {section!r} must be a mapping, got {values!r}")
        try:
            return build_config(SECTIONS[section], values, what=f"{where}: section {section!r}")
        except ConfigError as e:
            raise RecipeError(str(e)) from None

    built = {section: build(section) for section in SECTIONS}
    if sections.get("discriminator") is None or built["loss"].adv == 0:
        # none in the file, or never built nor trained without an adversarial term
        built["discriminator"] = None
    description = str(sections.get("description", ""))
    return Recipe(name=name, size=size, description=description, source=source, **built)


def read_recipe(name_or_path: str | Path) -> RecipeFile:
    """Read a recipe file (a registered name or a path) and its bases, once.

    Raises:
        RecipeError: an unknown recipe, a file that cannot be read, an unknown section, a base
            loop, naming the file.
    """
    path = recipe_path(name_or_path)
    sections, sizes = _resolve_file(path)
    name = Path(path).stem if Path(str(name_or_path)).suffix else str(name_or_path)
    return RecipeFile(path=path, name=name, sections=sections, sizes=sizes)


def load_recipe(
    name_or_path: str | Path, size: str = "paper", overrides: Mapping[str, Any] | None = None
) -> Recipe:
    """Read, merge and check a recipe: the file, its bases, the chosen size, then ``overrides``.

    Every size of the file is checked, not only ``size``: a bad value that the chosen size
    happens to override is still reported, naming the size it breaks. Checks cover each
    field's range, and settings that cannot work together (a resolution the generator cannot
    take, a discriminator that judges another number of renderings than the loss draws, ...),
    so that nothing fails later in the first step.

    Raises:
        RecipeError: an unknown recipe, section, field or size, or a value of the wrong type or
            out of range, naming the field, the value, the file and the size or override.
    """
    return read_recipe(name_or_path).recipe(size, overrides)


def recipe_from_dict(data: Mapping[str, Any], *, where: str = "recipe", check: bool = True) -> Recipe:
    """The :class:`Recipe` that ``Recipe.to_dict()`` wrote (e.g. into a checkpoint).

    Each section's fields are checked; with ``check`` False the settings that cannot work
    together are not (:func:`check_recipe`), for a recipe that is only compared, or checked
    once it is complete.

    Raises:
        RecipeError: ``data`` is not a mapping of sections, or a section or value is wrong;
            the message starts with ``where``.
    """
    if not isinstance(data, Mapping):
        raise RecipeError(f"{where}: a recipe is a mapping of sections, got {type(data).__name__}")
    optim = data.get("optim")
    if isinstance(optim, Mapping) and "decay_every_samples" not in optim:
        # written before schedules were counted in samples: its period was in epochs
        data = {**data, "optim": {**optim, "decay_every_samples": None}}
    try:
        sections = {
            name: (None if data.get(name) is None else build_config(cls, data[name], what=f"{where}: {name}"))
            for name, cls in SECTIONS.items()
        }
    except ConfigError as e:
        raise RecipeError(str(e)) from None
    recipe = Recipe(
        name=str(data.get("name", "recipe")),
        size=str(data.get("size", "paper")),
        description=str(data.get("description", "")),
        source=str(data.get("source", "")),
        **sections,
    )
    if check:
        check_recipe(recipe, where)
    return recipe


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out or {prefix[:-1]: {}}
    return {prefix[:-1]: value}


def recipe_differences(a: Recipe, b: Recipe, ignore: Iterable[str] = ()) -> list[str]:
    """Dotted fields whose values differ between two recipes (``"loss.adv: 0.1 -> 0.0"``).

    ``ignore`` lists dotted prefixes to leave out (e.g. ``"train.max_steps"``); the recipe's
    name, size, description and source file are not compared.
    """
    fa, fb = _flat(a.to_dict()), _flat(b.to_dict())
    skip = ("name", "size", "description", "source", *ignore)
    out = []
    for key in sorted(set(fa) | set(fb)):
        if any(key == p or key.startswith(p + ".") for p in skip):
            continue
        if fa.get(key, "(unset)") != fb.get(key, "(unset)"):
            out.append(f"{key}: {fa.get(key, '(unset)')!r} -> {fb.get(key, '(unset)')!r}")
    return out


def with_overrides(
    recipe: Recipe, overrides: Mapping[str, Any], where: str = "--set", *, check: bool = True
) -> Recipe:
    """``recipe`` with dotted ``overrides`` applied (as ``--set`` does), checked again (the
    settings that cannot work together only with ``check``, as :func:`recipe_from_dict`)."""
    if not overrides:
        return recipe
    data = recipe.to_dict()
    meta = {k: data.pop(k) for k in ("name", "size", "description", "source")}
    recipe_name = f"recipe {meta['source'] or meta['name']}"
    sections = _apply(data, overrides, f"{where} ({recipe_name})")
    given = ", ".join(f"{k}={show(v)}" for k, v in overrides.items())
    return recipe_from_dict({**sections, **meta}, where=f"{where} {given} ({recipe_name})", check=check)
