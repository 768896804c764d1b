"""svbrdf-models installs with svbrdf-render and torch only, and imports nothing heavy."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import requires


def test_dependencies_are_render_and_torch_only():
    reqs = requires("svbrdf-models") or []
    names = sorted(r.split(">")[0].split("=")[0].split("[")[0].strip() for r in reqs if "extra ==" not in r)
    assert names == ["svbrdf-render", "torch"]


def test_creating_networks_pulls_no_io_tracking_or_sibling():
    code = (
        "import sys, torch, svbrdf_models as sm\n"
        "g = sm.create_generator('ours', preset='tiny'); g(torch.rand(1, 3, 32, 32))\n"
        "sm.create_discriminator('patchgan', preset='tiny')\n"
        "bad = sorted(m for m in ('mlflow', 'h5py', 'PIL', 'yaml', 'click', 'svbrdf_train', 'svbrdf_bench') "
        "if m in sys.modules)\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""


def test_importing_the_photo_tool_pulls_no_trainer_tracking_io_or_compiler():
    """The photo tool (capture, its command line) sits below the trainer: importing it loads
    neither svbrdf-train, svbrdf-bench, mlflow, h5py nor click; Pillow and PyYAML only when a
    photo or scene is read; torch._dynamo (0.8 s) not at all."""
    code = (
        "import sys, svbrdf_models.capture.one, svbrdf_models.capture.batch, svbrdf_models.cli\n"
        "bad = sorted(m for m in ('mlflow', 'h5py', 'PIL', 'yaml', 'click', 'svbrdf_train', 'svbrdf_bench',"
        " 'torch._dynamo') if m in sys.modules)\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""
