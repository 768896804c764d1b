"""The model shipped inside svbrdf-models: present, small, documented, and runnable from a clean
virtual environment holding only svbrdf-models and svbrdf-render (and what they pull: torch, numpy)."""

from __future__ import annotations

import json
import subprocess
import venv

import pytest
import torch

import svbrdf_models as sm
from conftest import REPO
from svbrdf_models.modelfile.files import PRETRAINED, card_path, pretrained_path

MAX_BYTES = 20 * 10**6
#: Every model shipped in the package (``pretrained:NAME``); ``pretrained`` alone is PRETRAINED.
SHIPPED = sorted(p.stem for p in pretrained_path().parent.glob("*.pt"))


def test_pretrained_alone_is_the_default_shipped_model():
    assert PRETRAINED in SHIPPED
    assert sm.load_model("pretrained").source == f"pretrained:{PRETRAINED}"


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_model_is_small_loads_and_predicts(name):
    path = pretrained_path(name)
    assert path.stat().st_size <= MAX_BYTES
    model = sm.load_model(f"pretrained:{name}")
    assert model.source == f"pretrained:{name}"
    assert model.steps > 0 and model.provenance["train_seconds"] > 0
    maps = model.predict(torch.rand(3, 256, 256) * 0.5)
    assert maps.diffuse.shape == (1, 3, model.resolution, model.resolution)
    for m in ("normal", "diffuse", "roughness", "specular"):
        t = getattr(maps, m)
        assert torch.isfinite(t).all() and t.min() >= -1 and t.max() <= 1


@pytest.mark.parametrize("name", SHIPPED)
def test_its_card_says_how_it_was_made_and_how_it_does(name):
    card = card_path(name).read_text()
    model = sm.load_model(f"pretrained:{name}")
    needed_words = ("unseen-dev", "des18-dev", "`mean`", "render", "diffuse", "roughness", "specular", "Data", "Hardware")
    for needed in needed_words:
        assert needed in card, needed
    assert model.provenance["git_sha"][:7] in card
    assert f"{model.steps}" in card
    assert model.sha256 in card


def test_unknown_shipped_name_is_one_line():
    with pytest.raises(sm.ModelFileError, match="no such shipped model"):
        sm.load_model("pretrained:nope")


@pytest.mark.slow
def test_a_clean_environment_with_models_and_render_only_predicts(tmp_path):
    """pip install packages/svbrdf-models packages/svbrdf-render into a new virtual environment
    (not editable: the model must travel as package data), then load the shipped model and predict."""
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    install = subprocess.run(
        [str(python), "-m", "pip", "install", "--quiet", "-c", str(REPO / "constraints.txt"),
         str(REPO / "packages" / "svbrdf-models"), str(REPO / "packages" / "svbrdf-render")],
        capture_output=True, text=True, timeout=1200,
    )  # fmt: skip
    if install.returncode != 0 and "No matching distribution" in install.stderr:
        pytest.skip(f"pip cannot reach torch from here: {install.stderr[-300:]}")
    assert install.returncode == 0, install.stderr[-2000:]
    code = (
        "import importlib.util, json, torch, svbrdf_models as sm\n"
        "m = sm.load_model('pretrained')\n"
        "maps = m.predict(torch.rand(3, 256, 256) * 0.5)\n"
        "print(json.dumps({'name': m.name, 'resolution': m.resolution, 'shape': list(maps.diffuse.shape),\n"
        "  'finite': bool(torch.isfinite(maps.pack()).all()), 'file': sm.__file__,\n"
        "  'extra': [n for n in ('svbrdf_train', 'svbrdf_bench', 'mlflow', 'h5py', 'click')\n"
        "            if importlib.util.find_spec(n)]}))\n"
    )
    r = subprocess.run([str(python), "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    model = sm.load_model("pretrained")
    assert got["name"] == model.name and got["resolution"] == model.resolution
    assert got["shape"] == [1, 3, model.resolution, model.resolution] and got["finite"]
    assert got["extra"] == []  # nothing of training, benchmarking or tracking came along
    assert got["file"].startswith(str(env_dir))  # the installed copy, not this checkout
