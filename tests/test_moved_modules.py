"""Modules moved into subpackages (issues 38 and 48) keep their old names until a stated release:
the old name imports the very module under its new name, with a DeprecationWarning that says where
it went and which release removes it; no file stands at an old name (the old names are listed once,
in each package's _MOVED), and no alias outlives the release that removes it."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

import svbrdf_models
import svbrdf_render
import svbrdf_train

MOVED = {**svbrdf_render._MOVED, **svbrdf_models._MOVED, **svbrdf_train._MOVED}


@pytest.mark.parametrize(("old", "new"), sorted(MOVED.items()))
def test_an_old_module_name_is_the_new_module_with_a_warning(old, new):
    module = importlib.import_module(new)
    sys.modules.pop(old, None)
    package = importlib.import_module(old.split(".")[0])
    with pytest.warns(DeprecationWarning, match=rf"{old} moved to {new}: .* goes in {package._MOVED_UNTIL}"):
        assert importlib.import_module(old) is module
    top, _, leaf = old.rpartition(".")
    assert getattr(importlib.import_module(top), leaf) is module  # `import pkg.old` then `pkg.old.x` works


@pytest.mark.parametrize("old", sorted(MOVED))
def test_no_file_stands_at_an_old_name(old):
    top = importlib.import_module(old.split(".")[0])
    root = Path(top.__file__).parent.parent
    assert not (root / (old.replace(".", "/") + ".py")).exists()


def test_the_new_names_import_without_warnings(recwarn):
    for new in MOVED.values():
        importlib.import_module(new)
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning) and "moved to" in str(w.message)]


@pytest.mark.parametrize(
    "gone",
    ["svbrdf_render.rings", "svbrdf_models.serve", "svbrdf_models.reference", "svbrdf_train.capture",
     "svbrdf_models.capture.flashpoint", "svbrdf_models.capture.record", "svbrdf_render.refinement.prior"],
)  # fmt: skip
def test_aliases_of_paths_that_never_shipped_are_gone(gone):
    """Issue 48: these old names were never in a release (they moved or merged in the same round
    they were made), and svbrdf_train.capture was asked to go: none imports."""
    sys.modules.pop(gone, None)
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(gone)


def _release(version: str) -> tuple[int, ...]:
    return tuple(int(part) for part in version.split("."))


@pytest.mark.parametrize("package", [svbrdf_render, svbrdf_models, svbrdf_train], ids=lambda p: p.__name__)
def test_no_alias_outlives_the_release_that_removes_it(package):
    """Each package's aliases name the release that removes them, later than the package's own:
    a release at that version fails here until its aliases are deleted."""
    assert _release(package._MOVED_UNTIL) > _release(package.__version__)
