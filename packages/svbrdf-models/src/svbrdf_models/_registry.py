"""The registry: generators, attention modules and discriminators found through entry points.

Three entry-point groups, one per kind::

    svbrdf.generators       -> ModelSpec(kind="generator", ...)
    svbrdf.attention        -> ModelSpec(kind="attention", ...)
    svbrdf.discriminators   -> ModelSpec(kind="discriminator", ...)

svbrdf-models registers its own built-ins through these groups too (see its
pyproject.toml), so the path a third-party plugin takes is the one that always runs.

Discovery is lazy: importing :mod:`svbrdf_models` reads nothing; listing names reads the
installed distributions' metadata but imports no plugin; describing or creating a name
imports the module its entry point names, and only that one.
"""

from __future__ import annotations

import difflib
import fnmatch
import importlib.metadata
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ._config import FieldInfo, build_config, config_fields
from .errors import ConfigError, DuplicateNameError, PluginLoadError, RegistryError, UnknownNameError

__all__ = [
    "KINDS",
    "ModelSpec",
    "ModelInfo",
    "Registry",
    "default_registry",
    "list_models",
    "describe",
    "resolve_config",
    "check_input_size",
    "create",
    "create_generator",
    "create_attention",
    "create_discriminator",
]

#: kind -> entry-point group.
KINDS: dict[str, str] = {
    "generator": "svbrdf.generators",
    "attention": "svbrdf.attention",
    "discriminator": "svbrdf.discriminators",
}
_NOUNS = {"generator": "generator", "attention": "attention module", "discriminator": "discriminator"}

REINSTALL_HINT = (
    "An entry point that was added or edited after installation is not seen until its package "
    "is installed again (pip install -e PATH)."
)


@dataclass(frozen=True)
class ModelSpec:
    """What an entry point names: how to build one kind of network and how to configure it.

    Args:
        kind: ``"generator"``, ``"attention"`` or ``"discriminator"``; must match the group.
        build: called as ``build(config)`` for generators and discriminators and
            ``build(config, channels=C)`` for attention modules; returns an ``nn.Module``.
        config: a dataclass whose fields are declared with :func:`svbrdf_models.param`.
        description: one line, shown by ``svbrdf-models list``.
        defaults: field values that differ from the config class's own defaults; this is how
            one network class serves several names (``no-attn`` is ``ours`` with
            ``attention="none"``).
        presets: named partial configs, e.g. ``{"small": {"depth": 6, "base_channels": 16}}``.

    A config class may also declare, so that a bad config is refused before any layer is built:

    - ``sub_networks()`` -> ``(name field, config field, kind, name, config)`` of each
      registered module it will create (a generator's attention modules), which
      :meth:`Registry.resolve_config` resolves too.
    - ``check_input_size(height, width)``, raising ValueError for inputs the network cannot
      take (a U-Net's multiple of ``2**depth``); see :meth:`Registry.check_input_size`.

    Example (a plugin's module)::

        GATE = ModelSpec("attention", MyGate, MyGateConfig, "1x1 conv -> sigmoid gate")

    and in its pyproject.toml::

        [project.entry-points."svbrdf.attention"]
        my-gate = "my_plugin:GATE"
    """

    kind: str
    build: Callable[..., Any]
    config: type
    description: str
    defaults: Mapping[str, Any] = field(default_factory=dict)
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise RegistryError(f"ModelSpec kind {self.kind!r}: expected one of {', '.join(KINDS)}")


@dataclass(frozen=True)
class ModelInfo:
    """What :func:`describe` returns: a registered name, where it comes from, how to configure it."""

    kind: str
    name: str
    description: str
    distribution: str
    version: str
    target: str
    fields: tuple[FieldInfo, ...]
    presets: Mapping[str, Mapping[str, Any]]

    def format(self) -> str:
        """A human-readable page, as ``svbrdf-models describe`` prints it."""
        lines = [
            f"{self.name} ({_NOUNS[self.kind]}, from {self.distribution} {self.version}; {self.target})",
            f"  {self.description}",
            "",
            "config fields (name: type = default  doc):",
        ]
        for f in self.fields:
            choices = f"  [one of {', '.join(map(str, f.choices))}]" if f.choices else ""
            lines.append(f"  {f.name}: {f.type} = {f.default!r}")
            lines.append(f"      {f.doc}{choices}")
        if self.presets:
            lines += ["", "presets:"]
            for name, values in self.presets.items():
                lines.append(f"  {name}: {dict(values) or '(the defaults)'}")
        return "\n".join(lines)


@dataclass(frozen=True)
class _Entry:
    kind: str
    name: str
    target: str
    distribution: str
    version: str
    entry_point: Any


def _installed_entry_points(group: str) -> Iterable[Any]:
    return importlib.metadata.entry_points(group=group)


class Registry:
    """Entry points of the three kinds, scanned on first use and loaded one name at a time.

    Args:
        entry_points: ``group -> iterable of EntryPoint``; defaults to the installed
            distributions. Tests pass their own to simulate broken or duplicate plugins.
    """

    def __init__(self, entry_points: Callable[[str], Iterable[Any]] | None = None):
        self._source = entry_points or _installed_entry_points
        self._entries: dict[str, dict[str, list[_Entry]]] = {}
        self._specs: dict[tuple[str, str], ModelSpec] = {}
        self._failures: dict[tuple[str, str], str] = {}

    def refresh(self) -> None:
        """Forget what was scanned and loaded (after installing or removing a plugin)."""
        self._entries.clear()
        self._specs.clear()
        self._failures.clear()

    # -- discovery ----------------------------------------------------------------------

    def _scan(self, kind: str) -> dict[str, list[_Entry]]:
        _check_kind(kind)
        if kind not in self._entries:
            found: dict[str, list[_Entry]] = {}
            for ep in self._source(KINDS[kind]):
                dist = getattr(ep, "dist", None)
                dist_name = getattr(dist, "name", None) or "(unknown distribution)"
                version = getattr(dist, "version", None) or "?"
                entry = _Entry(kind, ep.name, ep.value, dist_name, version, ep)
                same = found.setdefault(ep.name, [])
                # One distribution visible twice on sys.path (an editable install plus a stale
                # copy) declares the same target: that is one entry, not a conflict.
                if not any((e.distribution, e.target) == (dist_name, ep.value) for e in same):
                    same.append(entry)
            self._entries[kind] = found
        return self._entries[kind]

    def names(self, kind: str, pattern: str = "*") -> list[str]:
        """Registered names of ``kind`` matching the shell-style ``pattern``, sorted. Imports nothing."""
        return sorted(n for n in self._scan(kind) if fnmatch.fnmatchcase(n, pattern))

    def sources(self, kind: str, name: str) -> list[str]:
        """The distributions that register ``name`` (two or more is a conflict). Imports nothing."""
        return [e.distribution for e in self._scan(kind).get(name, [])]

    def _entry(self, kind: str, name: str) -> _Entry:
        entries = self._scan(kind).get(name)
        if not entries:
            raise UnknownNameError(self._unknown_message(kind, name))
        if len(entries) > 1:
            who = " and ".join(f"{e.distribution} ({e.target})" for e in entries)
            raise DuplicateNameError(
                f"{_NOUNS[kind]} name {name!r} is registered by {who}; entry-point names in "
                f"{KINDS[kind]} must be unique. Uninstall or rename one of them."
            )
        return entries[0]

    def spec(self, kind: str, name: str) -> ModelSpec:
        """The ModelSpec behind ``name``, importing its module on first use."""
        key = (kind, name)
        if key in self._specs:
            return self._specs[key]
        entry = self._entry(kind, name)
        where = (
            f"{_NOUNS[kind]} {name!r} ({KINDS[kind]} entry point {entry.target!r} from {entry.distribution})"
        )
        try:
            obj = entry.entry_point.load()
        except Exception as e:  # an arbitrary plugin can fail in any way on import
            reason = f"{type(e).__name__}: {e}"
            self._failures[key] = reason
            raise PluginLoadError(f"{where} failed to load: {reason}. {REINSTALL_HINT}") from e
        if not isinstance(obj, ModelSpec) or obj.kind != kind:
            got = f"a ModelSpec of kind {obj.kind!r}" if isinstance(obj, ModelSpec) else type(obj).__name__
            reason = f"names {got}, expected a svbrdf_models.ModelSpec of kind {kind!r}"
            self._failures[key] = reason
            raise PluginLoadError(f"{where} {reason}")
        self._specs[key] = obj
        return obj

    def failures(self, kind: str) -> dict[str, str]:
        """Names of ``kind`` whose plugin cannot be loaded, with the reason. Loads every entry."""
        for name, entries in self._scan(kind).items():
            if len(entries) == 1 and (kind, name) not in self._specs:
                try:
                    self.spec(kind, name)
                except PluginLoadError:
                    pass
        return {n: r for (k, n), r in self._failures.items() if k == kind}

    def _unknown_message(self, kind: str, name: str) -> str:
        noun = _NOUNS[kind]
        entries = self._scan(kind)
        lines = [f"unknown {noun} {name!r}."]
        close = difflib.get_close_matches(name, list(entries), n=3, cutoff=0.5)
        if close:
            lines[0] += f" Did you mean {' or '.join(repr(c) for c in close)}?"
        by_dist: dict[str, list[str]] = {}
        for n, es in sorted(entries.items()):
            for e in es:
                by_dist.setdefault(e.distribution, []).append(n)
        if by_dist:
            listed = "; ".join(f"{', '.join(ns)} (from {d})" for d, ns in sorted(by_dist.items()))
            lines.append(f"Available {noun}s: {listed}.")
        else:
            lines.append(f"No {noun} is registered: is svbrdf-models installed in this environment?")
        failed = self.failures(kind)
        if failed:
            lines.append(
                "Plugins that failed to load: "
                + "; ".join(f"{n}: {r}" for n, r in sorted(failed.items()))
                + "."
            )
        lines.append(REINSTALL_HINT)
        return " ".join(lines)

    # -- description and creation -----------------------------------------------------------

    def describe(self, kind: str, name: str) -> ModelInfo:
        """Where ``name`` comes from and its config fields with defaults (imports its module)."""
        spec = self.spec(kind, name)
        entry = self._entry(kind, name)
        return ModelInfo(
            kind,
            name,
            spec.description,
            entry.distribution,
            entry.version,
            entry.target,
            config_fields(spec.config, spec.defaults),
            dict(spec.presets),
        )

    def resolve_config(self, kind: str, name: str, config: Mapping[str, Any] | None = None):
        """The full config instance: the spec's defaults, then ``config["preset"]``, then ``config``."""
        spec = self.spec(kind, name)
        what = f"{_NOUNS[kind]} {name!r}"
        values = dict(config or {})
        preset = values.pop("preset", None)
        merged = dict(spec.defaults)
        if preset is not None:
            if preset not in spec.presets:
                close = difflib.get_close_matches(str(preset), list(spec.presets), n=2, cutoff=0.5)
                hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
                known = ", ".join(spec.presets) or "none"
                raise RegistryError(f"{what}: unknown preset {preset!r}.{hint} Presets: {known}.")
            merged.update(spec.presets[preset])
        config = build_config(spec.config, values, what=what, defaults=merged)
        subs = getattr(config, "sub_networks", None)
        for name_field, config_field, sub_kind, sub_name, sub_config in subs() if callable(subs) else ():
            try:
                self.resolve_config(sub_kind, sub_name, sub_config)
            except RegistryError as e:
                field_name = config_field if isinstance(e, ConfigError) else name_field
                raise type(e)(f"{what}: field {field_name!r}: {e}") from None
        return config

    def check_input_size(
        self, kind: str, name: str, config: Mapping[str, Any] | None, height: int, width: int | None = None
    ) -> None:
        """Refuse ``height x width`` inputs that ``name`` with ``config`` cannot take (a U-Net's
        size must be a multiple of ``2**depth``), before any layer is built.

        Raises:
            ConfigError: naming the network and what sizes it takes.
        """
        resolved = self.resolve_config(kind, name, config)
        check = getattr(resolved, "check_input_size", None)
        if callable(check):
            try:
                check(height, height if width is None else width)
            except ValueError as e:
                raise ConfigError(f"{_NOUNS[kind]} {name!r}: {e}") from None

    def create(self, kind: str, name: str, config: Mapping[str, Any] | None = None, **runtime):
        """Build ``name`` from a config dict (which may hold ``"preset"``); see ModelSpec.build."""
        spec = self.spec(kind, name)
        module = spec.build(self.resolve_config(kind, name, config), **runtime)
        if kind == "attention" and not isinstance(getattr(module, "out_channels", None), int):
            raise RegistryError(
                f"attention module {name!r} (from {', '.join(self.sources(kind, name))}) has no integer "
                "'out_channels' attribute; generators need it to size the next layer"
            )
        return module


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        close = difflib.get_close_matches(str(kind), list(KINDS), n=1)
        hint = f" Did you mean {close[0]!r}?" if close else ""
        raise RegistryError(f"unknown kind {kind!r}.{hint} Kinds: {', '.join(KINDS)}.")


_DEFAULT = Registry()


def default_registry() -> Registry:
    """The registry over the installed distributions that the module-level functions use."""
    return _DEFAULT


def list_models(kind: str = "generator", pattern: str = "*") -> list[str]:
    """Registered names of ``kind`` matching the shell-style ``pattern``, sorted; imports no plugin.

    Example: ``list_models("attention", "c*")`` -> ``["cbam"]``.
    """
    return _DEFAULT.names(kind, pattern)


def describe(kind: str, name: str) -> ModelInfo:
    """A registered name's source, description, config fields (with defaults) and presets."""
    return _DEFAULT.describe(kind, name)


def resolve_config(kind: str, name: str, config: Mapping[str, Any] | None = None):
    """The complete config dataclass that ``create`` would use (log it with every run)."""
    return _DEFAULT.resolve_config(kind, name, config)


def check_input_size(
    kind: str, name: str, config: Mapping[str, Any] | None, height: int, width: int | None = None
) -> None:
    """Refuse input sizes a network cannot take, naming it (see :meth:`Registry.check_input_size`)."""
    _DEFAULT.check_input_size(kind, name, config, height, width)


def create(kind: str, name: str, config: Mapping[str, Any] | None = None, **runtime):
    """Build a registered network from its name and a config dict."""
    return _DEFAULT.create(kind, name, config, **runtime)


def _with_preset(config: Mapping[str, Any] | None, preset: str | None) -> dict[str, Any]:
    values = dict(config or {})
    if preset is not None:
        values["preset"] = preset
    return values


def create_generator(
    name: str = "ours", config: Mapping[str, Any] | None = None, *, preset: str | None = None
):
    """A generator: photo ``(B, 3, H, W)`` in, :class:`~svbrdf_render.SVBRDF` out.

    Example:
        >>> g = create_generator("ours", preset="tiny")
        >>> maps = g(torch.rand(1, 3, 64, 64))
    """
    return _DEFAULT.create("generator", name, _with_preset(config, preset))


def create_attention(name: str, channels: int, config: Mapping[str, Any] | None = None):
    """An attention module for ``channels`` input channels; its ``out_channels`` says what it returns."""
    return _DEFAULT.create("attention", name, config, channels=channels)


def create_discriminator(
    name: str = "patchgan", config: Mapping[str, Any] | None = None, *, preset: str | None = None
):
    """A discriminator: ``D(maps=SVBRDF, renderings=(B, N, 3, H, W))`` -> list of logit maps."""
    return _DEFAULT.create("discriminator", name, _with_preset(config, preset))
