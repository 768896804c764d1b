"""svbrdf-train's dependencies and imports: h5py and mlflow only when used."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import requires


def test_dependencies():
    reqs = requires("svbrdf-train") or []
    names = {r.split(">")[0].split("=")[0].split("[")[0].split(";")[0].strip() for r in reqs}
    assert {"svbrdf-render", "svbrdf-models", "h5py", "pyyaml", "click", "torch", "mlflow"} <= names
    assert not {"svbrdf-bench", "scikit-image"} & names


def test_data_package_loads_h5py_only_with_shards():
    code = (
        "import sys, svbrdf_train.data as d\n"
        "before = 'h5py' in sys.modules\n"
        "d.ShardDataset\n"
        "print(before, 'h5py' in sys.modules, 'mlflow' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True", "False"]


def test_public_names_resolve():
    import svbrdf_train.data as d

    for name in d.__all__:
        assert getattr(d, name) is not None


def test_trainer_and_cli_import_without_mlflow():
    """mlflow (~2 s to import) loads when a fit starts tracking, not with the trainer or the CLI."""
    code = (
        "import sys, svbrdf_train.training.trainer, svbrdf_train.predict, svbrdf_train.cli\n"
        "print('mlflow' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False"]


def test_inference_and_predict_import_no_training_code():
    """Rebuilding a generator and predicting with it sits below the trainer: neither the
    trainer, its losses, its training data nor mlflow load with them."""
    code = (
        "import sys, svbrdf_train.inference, svbrdf_train.predict\n"
        "names = ['svbrdf_train.training.trainer', 'svbrdf_train.training.losses', 'svbrdf_train.data.fitdata', 'mlflow']\n"
        "print(*[n for n in names if n in sys.modules] or ['none'])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["none"]
