"""Knowledge that used to be written in several places is written once (issue 38), found by
reading the four packages' source (:mod:`ast`; nothing is imported): the accuracy figures, the
renderer's backend names, the flash modes, the refinement budget's check and the reading of a
positive number from text."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _sources() -> list[tuple[str, ast.Module]]:
    out = []
    for path in sorted((REPO / "packages").glob("*/src/*/**/*.py")):
        if "egg-info" in str(path) or "/build/" in str(path):
            continue
        out.append((str(path.relative_to(REPO)), ast.parse(path.read_text(), filename=str(path))))
    return out


SOURCES = _sources()


def _defined(name: str) -> list[str]:
    """Where a function ``name`` is defined (module level or in a class)."""
    return [
        path
        for path, tree in SOURCES
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == name
    ]


def _literals_with(*words: str) -> list[str]:
    """``path:line`` of every tuple, list or set literal holding all of ``words`` as strings."""
    out = []
    for path, tree in SOURCES:
        for node in ast.walk(tree):
            if isinstance(node, ast.Tuple | ast.List | ast.Set):
                strings = {e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
                if set(words) <= strings:
                    out.append(f"{path}:{node.lineno}")
    return out


def _strings_containing(text: str) -> list[str]:
    """``path:line`` of every string constant (f-string parts too) that contains ``text``."""
    return [
        f"{path}:{node.lineno}"
        for path, tree in SOURCES
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and text in node.value
    ]


@pytest.mark.parametrize("name", ["per_sample_rmse", "map_rmse", "render_rmse", "display_rendering"])
def test_the_accuracy_figures_are_defined_once_in_svbrdf_render_compare(name):
    assert _defined(name) == ["packages/svbrdf-render/src/svbrdf_render/compare.py"], _defined(name)


def test_the_renderer_backend_names_are_listed_once():
    found = _literals_with("eager", "compiled")
    assert [f.rsplit(":", 1)[0] for f in found] == ["packages/svbrdf-render/src/svbrdf_render/renderer.py"], found


def test_the_flash_modes_are_listed_once():
    found = _literals_with("axis", "fit")
    assert [f.rsplit(":", 1)[0] for f in found] == [
        "packages/svbrdf-render/src/svbrdf_render/refinement/fit.py"
    ], found


def test_the_refinement_budget_is_checked_in_one_place():
    """One check of a refinement budget (svbrdf_models.capture.refining.check_refine) says what a
    budget must be; the renderer's own check of its arguments is the other layer's."""
    found = _strings_containing("whole number of refinement steps")
    assert [f.rsplit(":", 1)[0] for f in found] == [
        "packages/svbrdf-models/src/svbrdf_models/capture/refining.py"
    ], found
    assert _defined("check_refine") == ["packages/svbrdf-models/src/svbrdf_models/capture/refining.py"]


def test_a_positive_number_is_read_from_text_in_one_place():
    """``svbrdf_render.plumbing.positive_number`` reads "a finite number > 0" from text; the download
    timeout (svbrdf-models) and the benchmark's flash intensity (svbrdf-bench) use it."""
    assert _defined("positive_number") == ["packages/svbrdf-render/src/svbrdf_render/plumbing/arguments.py"]
    users = {
        path
        for path, tree in SOURCES
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        and node.module == "svbrdf_render.plumbing"
        and any(alias.name == "positive_number" for alias in node.names)
    }
    assert users >= {
        "packages/svbrdf-bench/src/svbrdf_bench/refinement.py",
        "packages/svbrdf-models/src/svbrdf_models/modelfile/download.py",
    }, users


def test_the_finders_find_what_they_look_for():
    """The search itself: a literal, a definition and a string planted in a parsed module are found."""
    tree = ast.parse('X = ("eager", "compiled")\ndef per_sample_rmse(): return "whole number of refinement steps"\n')
    SOURCES.append(("planted.py", tree))
    try:
        assert "planted.py:1" in _literals_with("eager", "compiled")
        assert "planted.py" in _defined("per_sample_rmse")
        assert "planted.py:2" in _strings_containing("whole number of refinement steps")
    finally:
        SOURCES.remove(("planted.py", tree))
