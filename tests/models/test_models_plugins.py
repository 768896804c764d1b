"""The plugin example (tests/plugins/svbrdf-example-plugin, installed by scripts/setup) adds an
attention module and a discriminator that are listed, created and used by name, with no change
to svbrdf-models."""

from __future__ import annotations

import importlib.util

import pytest
import torch

import svbrdf_models as sm
from conftest import REPO, random_svbrdf
from svbrdf_models.cli import main as models_cli
from svbrdf_render import render, training_scene

PLUGIN_DIR = REPO / "tests" / "plugins" / "svbrdf-example-plugin"


@pytest.fixture(autouse=True)
def plugin_installed():
    if importlib.util.find_spec("svbrdf_example_plugin") is None:
        pytest.fail(f"the example plugin is not installed; run scripts/setup (it installs {PLUGIN_DIR})")


def test_plugin_names_are_listed_with_their_package():
    assert "spatial-gate" in sm.list_models("attention")
    assert "pixelgan" in sm.list_models("discriminator")
    assert sm.describe("attention", "spatial-gate").distribution == "svbrdf-example-plugin"
    assert sm.default_registry().sources("discriminator", "pixelgan") == ["svbrdf-example-plugin"]


def test_cli_lists_the_plugin(capsys):
    assert models_cli(["list", "--kind", "attention"]) == 0
    line = next(row for row in capsys.readouterr().out.splitlines() if " spatial-gate " in row)
    assert "svbrdf-example-plugin" in line and "per-pixel sigmoid gate" in line


def test_plugin_attention_is_used_by_the_generator_by_name():
    from svbrdf_example_plugin import SpatialGate

    g = sm.create_generator(
        "ours", {"preset": "tiny", "attention": "spatial-gate", "attention_config": {"bias": 1.0}}
    )
    assert all(isinstance(b.attention, SpatialGate) for b in g.down)
    assert float(g.down[0].attention.logit.bias.detach()) == 1.0
    maps = g(torch.rand(2, 3, 32, 32))
    assert maps.shape == (2, 32, 32)
    maps.pack().sum().backward()
    assert g.down[0].attention.logit.weight.grad.abs().sum() > 0


def test_plugin_discriminator_judges_renderings():
    d = sm.create_discriminator("pixelgan", preset="tiny")
    maps = random_svbrdf(2, 16)
    (logits,) = d(maps=maps, renderings=render(maps, training_scene(2)))
    assert logits.shape == (2, 1, 16, 16) and torch.isfinite(logits).all()


def test_svbrdf_models_does_not_mention_the_plugin():
    src = REPO / "packages" / "svbrdf-models"
    text = "".join(p.read_text() for p in src.rglob("*") if p.suffix in (".py", ".toml", ".md"))
    assert "spatial-gate" not in text and "pixelgan" not in text and "example_plugin" not in text
