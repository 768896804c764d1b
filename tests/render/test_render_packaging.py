"""svbrdf-render installs alone: torch and numpy only, nothing heavy imported."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import requires

import pytest

from conftest import REPO


def test_core_dependencies_are_torch_and_numpy_only():
    reqs = requires("svbrdf-render") or []
    core = sorted(r.split(">")[0].split("=")[0].strip() for r in reqs if "extra ==" not in r)
    assert core == ["numpy", "torch"]


def test_importing_the_renderer_pulls_no_io_or_tracking_library():
    code = (
        "import sys, svbrdf_render\n"
        "from svbrdf_render import render, Scene, SVBRDF\n"
        "render(SVBRDF.constant(1, 4), Scene())\n"
        "bad = sorted(m for m in ('mlflow', 'h5py', 'PIL', 'png', 'yaml', 'svbrdf_models', "
        "'svbrdf_train', 'svbrdf_bench', 'skimage') if m in sys.modules)\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""


@pytest.mark.slow
def test_pip_resolves_no_sibling_or_heavy_dependency(tmp_path):
    # Ask pip what a plain install would bring, against the index, without installing.
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
         "--report", str(tmp_path / "report.json"), "-c", str(REPO / "constraints.txt"),
         str(REPO / "packages" / "svbrdf-render")],
        capture_output=True, text=True,
    )
    if r.returncode != 0:
        pytest.skip(f"pip could not resolve against the index here: {r.stderr[-300:]}")
    import json

    names = {i["metadata"]["name"].lower() for i in json.loads((tmp_path / "report.json").read_text())["install"]}
    assert "torch" in names and "numpy" in names
    for heavy in ("mlflow", "h5py", "pillow", "pyyaml", "pypng", "svbrdf-models", "svbrdf-train", "svbrdf-bench"):
        assert heavy not in names
