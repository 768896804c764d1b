"""Config dataclasses: fields with one-line docs, built from plain dicts with checked types.

Every registered model, attention module and discriminator is configured by a frozen
dataclass whose fields are declared with :func:`param`. The doc string of each field is
what ``svbrdf-models describe`` prints, and a dict from a YAML recipe is turned into the
dataclass by :func:`build_config`, which names unknown keys (with close matches) and values
of the wrong type instead of failing deep inside a constructor.
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Union

from .errors import ConfigError

__all__ = ["param", "FieldInfo", "config_fields", "build_config", "config_to_dict"]


def param(default: Any, doc: str, *, choices: tuple | None = None) -> Any:
    """A config field with a one-line ``doc`` and, optionally, the allowed ``choices``.

    Mutable defaults (dict, list) are copied per instance.
    """
    meta = {"doc": doc, "choices": choices}
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclass(frozen=True)
class FieldInfo:
    """One configurable field: its name, type as written, default, doc and allowed values."""

    name: str
    type: str
    default: Any
    doc: str
    choices: tuple | None = None


def _type_hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def config_fields(cls, defaults: Mapping[str, Any] | None = None) -> tuple[FieldInfo, ...]:
    """The fields of config class ``cls``, with ``defaults`` overriding the declared ones."""
    defaults = defaults or {}
    hints = _type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in defaults:
            default = defaults[f.name]
        elif f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None
        out.append(
            FieldInfo(
                f.name,
                _type_name(hints.get(f.name, Any)),
                default,
                f.metadata.get("doc", ""),
                f.metadata.get("choices"),
            )
        )
    return tuple(out)


def _type_name(tp) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any) -> Any:
    """``value`` converted to annotation ``tp``; TypeError when it does not fit.

    Covers the types configs use: bool, int, float, str, dict, ``tuple[T, ...]`` (a list from
    YAML is accepted) and unions of those, including ``None``.
    """
    if tp is Any:
        return value
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        for arg in typing.get_args(tp):
            try:
                return _coerce(value, arg)
            except TypeError:
                continue
        raise TypeError
    if tp is type(None):
        if value is None:
            return None
        raise TypeError
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise TypeError
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0]) for v in value)
        if len(args) != len(value):
            raise TypeError
        return tuple(_coerce(v, a) for v, a in zip(value, args, strict=True))
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise TypeError
        return dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise TypeError
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise TypeError
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise TypeError
    if tp is str:
        if isinstance(value, str):
            return value
        raise TypeError
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise TypeError


def build_config(
    cls, values: Mapping[str, Any] | None, *, what: str, defaults: Mapping[str, Any] | None = None
):
    """An instance of config class ``cls`` from ``defaults`` overridden by ``values``.

    Args:
        what: how to name the thing being configured in errors, e.g. ``"generator 'ours'"``.

    Raises:
        ConfigError: an unknown key (with close matches and the valid keys), a value of the
            wrong type, a value outside ``choices``, or a ValueError from the class's checks.
    """
    hints = _type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    merged = dict(defaults or {})
    merged.update(values or {})
    kwargs = {}
    for key, value in merged.items():
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=3)
            hint = f" Did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            raise ConfigError(
                f"{what}: unknown config field {key!r}.{hint} Valid fields: {', '.join(fields)}."
            )
        try:
            value = _coerce(value, hints.get(key, Any))
        except TypeError:
            raise ConfigError(
                f"{what}: field {key!r} expects {_type_name(hints.get(key, Any))}, "
                f"got {value!r} ({type(value).__name__})"
            ) from None
        choices = fields[key].metadata.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(
                f"{what}: field {key!r} must be one of {', '.join(map(repr, choices))}, got {value!r}"
            )
        kwargs[key] = value
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as e:
        raise ConfigError(f"{what}: {e}") from None


def config_to_dict(config) -> dict[str, Any]:
    """A plain dict of a config instance (tuples stay tuples; nested dicts are copied)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
