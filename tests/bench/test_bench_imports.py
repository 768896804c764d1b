"""svbrdf-bench uses svbrdf-train through its public API alone: the names of ``svbrdf_train.__all__``,
imported from the package itself (read from the source with :mod:`ast`, as tests/test_structure.py
does), and that API costs nothing to import until a name is used."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import svbrdf_train

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "packages" / "svbrdf-bench" / "src" / "svbrdf_bench"


def _private_uses(source: str, public: set[str]) -> list[str]:
    """Every import of ``source`` that reaches into svbrdf_train past its public API, as
    ``line: what``: a submodule (``svbrdf_train.tracking``), or a name not in ``public``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [
                f"{node.lineno}: import {a.name}" for a in node.names if a.name.startswith("svbrdf_train.")
            ]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.startswith("svbrdf_train."):
                out.append(f"{node.lineno}: from {node.module} import ...")
            elif node.module == "svbrdf_train":
                out += [f"{node.lineno}: {a.name} (not public)" for a in node.names if a.name not in public]
    return out


def test_the_bench_imports_only_the_public_api_of_svbrdf_train():
    public = set(svbrdf_train.__all__)
    found = []
    for path in sorted(BENCH.rglob("*.py")):
        found += [f"{path.relative_to(REPO)}:{u}" for u in _private_uses(path.read_text(), public)]
    assert not found, "svbrdf_bench reaches past svbrdf_train.__all__:\n" + "\n".join(found)


def test_the_check_sees_submodules_and_private_names():
    source = (
        "import svbrdf_train\n"
        "from svbrdf_train import load_recipe\n"
        "def f():\n"
        "    from svbrdf_train.tracking import ui_page\n"  # inside a function, as the bench's are
        "    import svbrdf_train.training.clock\n"
        "    from svbrdf_train import _PUBLIC\n"
    )
    assert _private_uses(source, {"load_recipe"}) == [
        "4: from svbrdf_train.tracking import ...",
        "5: import svbrdf_train.training.clock",
        "6: _PUBLIC (not public)",
    ]


@pytest.mark.parametrize("name", sorted(set(svbrdf_train.__all__) - {"__version__"}))
def test_every_public_name_is_the_object_of_its_module(name):
    """Each name of ``__all__`` resolves, to the very object its module defines (no copy)."""
    import importlib

    module = importlib.import_module(svbrdf_train._WHERE[name], "svbrdf_train")
    assert getattr(svbrdf_train, name) is getattr(module, name)


def test_importing_the_package_imports_neither_torch_nor_mlflow():
    code = (
        "import sys, svbrdf_train\n"
        "assert 'torch' not in sys.modules and 'mlflow' not in sys.modules, 'heavy import'\n"
        "svbrdf_train.CLOCK_TAG\n"  # a name of a light module: still no mlflow
        "assert 'mlflow' not in sys.modules, 'mlflow imported by a name'\n"
        "try:\n"
        "    svbrdf_train.no_such_name\n"
        "except AttributeError as e:\n"
        "    assert 'no_such_name' in str(e)\n"
        "else:\n"
        "    raise AssertionError('an unknown name resolved')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_names_of_other_packages_come_from_their_owners():
    """Issue 48: a name svbrdf_train only passes on (defined in svbrdf_render or svbrdf_models) is
    imported from the package that defines it, so that it has one address in svbrdf-bench."""
    borrowed = []
    for path in sorted(BENCH.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "svbrdf_train":
                for alias in node.names:
                    owner = getattr(getattr(svbrdf_train, alias.name), "__module__", None) or "svbrdf_train"
                    if not owner.startswith("svbrdf_train"):
                        borrowed.append(f"{path.name}:{node.lineno}: {alias.name} (from {owner})")
    assert not borrowed, borrowed
