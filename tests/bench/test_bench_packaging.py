"""svbrdf-bench's dependencies, and a command line that starts without the heavy imports."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import requires


def test_dependencies_are_the_siblings_scikit_image_and_the_report_tools():
    reqs = requires("svbrdf-bench") or []
    names = {r.split(">")[0].split("=")[0].split("[")[0].split(";")[0].strip() for r in reqs}
    assert {"svbrdf-render", "svbrdf-models", "svbrdf-train", "scikit-image", "matplotlib", "mlflow"} <= names


def test_help_imports_no_mlflow_skimage_or_matplotlib():
    code = (
        "import sys\n"
        "from svbrdf_bench.cli import main\n"
        "try:\n"
        "    main(['run', '--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "print('loaded:' + ','.join(m for m in ('mlflow', 'skimage', 'matplotlib') if m in sys.modules))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip().splitlines()[-1] == "loaded:"
