"""What every package of the workspace shares: the licence, type hints, one version, and command
lines that answer ``--version`` and run as ``python -m``."""

from __future__ import annotations

import importlib.metadata

import pytest
import tomllib

from conftest import REPO

#: distribution name -> import name
PACKAGES = {
    "svbrdf-render": "svbrdf_render",
    "svbrdf-models": "svbrdf_models",
    "svbrdf-train": "svbrdf_train",
    "svbrdf-bench": "svbrdf_bench",
}


def _pyproject(dist: str) -> dict:
    with open(REPO / "packages" / dist / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def test_the_repository_has_the_mit_licence_the_packages_declare():
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License\n")
    assert "Copyright (c)" in text and "the svbrdf developers" in text
    assert 'THE SOFTWARE IS PROVIDED "AS IS"' in text


@pytest.mark.parametrize("dist", PACKAGES)
def test_each_package_ships_the_licence(dist):
    """Each package holds a copy of the root LICENSE (a package cannot name a file outside its
    folder), names it in license-files, and its installed metadata lists it."""
    project = _pyproject(dist)["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert (REPO / "packages" / dist / "LICENSE").read_text() == (REPO / "LICENSE").read_text()
    assert importlib.metadata.metadata(dist).get_all("License-File") == ["LICENSE"]


@pytest.mark.parametrize(("dist", "module"), PACKAGES.items())
def test_each_package_is_marked_typed(dist, module):
    """PEP 561: py.typed in the package, and named as package data so that wheels carry it."""
    assert (REPO / "packages" / dist / "src" / module / "py.typed").is_file()
    assert "py.typed" in _pyproject(dist)["tool"]["setuptools"]["package-data"][module]
