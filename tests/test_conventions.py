"""What every package of the workspace shares: the licence, type hints, one version, and command
lines that answer ``--version`` and run as ``python -m``."""

from __future__ import annotations

import importlib
import importlib.metadata
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

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


@pytest.mark.parametrize(("dist", "module"), PACKAGES.items())
def test_the_version_has_one_source(dist, module):
    """``__version__`` is the only place the version is written: pyproject.toml reads it."""
    config = _pyproject(dist)
    assert "version" not in config["project"] and config["project"]["dynamic"] == ["version"]
    assert config["tool"]["setuptools"]["dynamic"]["version"] == {"attr": f"{module}.__version__"}
    assert importlib.import_module(module).__version__ == importlib.metadata.version(dist)


@pytest.mark.slow
@pytest.mark.parametrize(("dist", "module"), PACKAGES.items())
def test_a_built_wheel_carries_py_typed_the_licence_and_the_version(dist, module, tmp_path):
    # Built from a copy: setuptools writes build/ and egg-info beside the sources it builds.
    source = shutil.copytree(REPO / "packages" / dist, tmp_path / dist,
                             ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path), str(source)],
        capture_output=True, text=True,
    )  # fmt: skip
    if r.returncode != 0:
        pytest.skip(f"pip could not build here (build dependencies from the index): {r.stderr[-300:]}")
    (wheel,) = tmp_path.glob("*.whl")
    version = importlib.import_module(module).__version__
    assert wheel.name.startswith(f"{module}-{version}-")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        info = f"{module}-{version}.dist-info"
        assert f"{module}/py.typed" in names
        # every file beside the code (the viewer's page template, the shipped model...): what
        # is in the source folder and not in the wheel would be missing from a pip install
        src = REPO / "packages" / dist / "src" / module
        files = {f"{module}/{p.relative_to(src).as_posix()}" for p in src.rglob("*")
                 if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts}  # fmt: skip
        assert files and files <= names, sorted(files - names)
        assert z.read(f"{info}/licenses/LICENSE").decode() == (REPO / "LICENSE").read_text()
        metadata = z.read(f"{info}/METADATA").decode()
    assert f"Version: {version}\n" in metadata and "License-Expression: MIT\n" in metadata


def _command(how: str, dist: str, module: str) -> list[str]:
    """The command line ``dist`` started as a console script or as ``python -m``."""
    if how == "python -m":
        return [sys.executable, "-m", module]
    script = Path(sys.executable).parent / dist
    if not script.is_file():
        pytest.skip(f"no console script {script} beside this interpreter")
    return [str(script)]


@pytest.mark.parametrize("how", ["python -m", "script"])
@pytest.mark.parametrize(("dist", "module"), PACKAGES.items())
def test_every_command_line_says_its_version(how, dist, module):
    r = subprocess.run([*_command(how, dist, module), "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{dist} {importlib.metadata.version(dist)}\n"


@pytest.mark.parametrize(("dist", "module"), PACKAGES.items())
def test_every_command_line_runs_as_python_m(dist, module):
    """``python -m svbrdf_X --help`` is the command itself, under its own name, --version listed."""
    r = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.lower().startswith(f"usage: {dist} ") and "--version" in r.stdout
