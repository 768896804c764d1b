"""Modules that moved into subpackages: their old names keep working until a stated release.

Each package of the project lists its moved modules (``{"old.name": "new.name"}``) with the
release that removes them (``_MOVED_UNTIL``) and calls :func:`install` when it is imported. Importing an old name then gives the module under its new
name (the same module object: what one patches, the other sees) and a
:class:`DeprecationWarning` that says where it went. A module split into several names the
subpackage whose ``__init__`` states their names (its names all import from there; a patch of
one there does not reach the module that uses it). No file stands at the old name. The
CHANGELOG's "Deprecated" says which names go in which release.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

__all__ = ["install", "spec_for"]


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """A finder and loader of old module names: each is the module under its new name."""

    def __init__(self, moves: dict[str, str], until: str):
        self.moves, self.until = dict(moves), until

    def find_spec(self, fullname, path=None, target=None):
        return importlib.util.spec_from_loader(fullname, self) if fullname in self.moves else None

    def create_module(self, spec):
        new = self.moves[spec.name]
        warnings.warn(f"{spec.name} moved to {new}: import it from there; the old name goes in "
                      f"{self.until} (CHANGELOG.md)", DeprecationWarning, stacklevel=2)  # fmt: skip
        return importlib.import_module(new)

    def exec_module(self, module) -> None:  # the module is the new one, already executed
        pass


def spec_for(fullname: str, moves: dict[str, str], until: str):
    """The import spec of old name ``fullname`` of ``moves`` (None for another name): for a
    package that must not import this one (and torch) before an old name is asked for."""
    return _MovedModules(moves, until).find_spec(fullname)


def install(moves: dict[str, str], until: str) -> None:
    """Let the old names of ``moves`` import their new modules (once per table) until release
    ``until``, which the warning names."""
    if not any(isinstance(f, _MovedModules) and f.moves == moves for f in sys.meta_path):
        sys.meta_path.append(_MovedModules(moves, until))
