"""The examples in the packages' docstrings (``>>>`` lines) run as doctests.

Every module under ``packages/*/src`` whose source holds an example is imported and its
docstrings run by :mod:`doctest`, in a temporary working folder (examples write files such as
``grid.png``). That folder holds ``DATA``, a link to the reference data, so the examples that
read it run where it is present; a module whose examples read ``DATA`` is skipped with a reason
where it is absent, as the other tests that read it are.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest
import torch

from conftest import REPO, SHARED_DATA

#: Output of examples is compared loosely: torch prints shapes and numbers with its own spacing.
OPTIONS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _modules_with_examples() -> list[tuple[str, Path]]:
    out = []
    for src in sorted((REPO / "packages").glob("*/src")):
        for path in sorted(src.rglob("*.py")):
            if ">>>" not in path.read_text():
                continue
            parts = list(path.relative_to(src).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out.append((".".join(parts), path))
    return out


MODULES = _modules_with_examples()


def test_examples_are_found():
    # The finder itself: the renderer's SVBRDF class has examples, so an empty list means the
    # search is broken, not that there is nothing to run.
    assert "svbrdf_render.maps" in {name for name, _ in MODULES}


@pytest.mark.parametrize("name, path", MODULES, ids=[name for name, _ in MODULES])
def test_docstring_examples_run(name, path, tmp_path, monkeypatch):
    if "DATA/" in path.read_text() and not SHARED_DATA.is_dir():
        pytest.skip(f"its examples read DATA ({SHARED_DATA} is absent)")
    if SHARED_DATA.is_dir():
        (tmp_path / "DATA").symlink_to(SHARED_DATA, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder(exclude_empty=True).find(module, name, globs={"torch": torch})
    examples = [t for t in tests if t.examples]
    assert examples, f"{path}: '>>>' in the source but no example doctest can find"
    runner = doctest.DocTestRunner(optionflags=OPTIONS)
    for test in examples:
        test.globs = {**vars(module), **test.globs}
        runner.run(test)
    failed, attempted = runner.summarize(verbose=False)
    assert failed == 0, f"{failed} of {attempted} examples of {name} failed (output above)"
