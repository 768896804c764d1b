"""A fit reads its recipe files once and checks its recipe once; a resume reads its checkpoint once.

The command runs in this process (click's runner) with the readers wrapped to count their calls:
the recipe files (``svbrdf_train.recipe.files._read_yaml``), the checks
(:func:`svbrdf_train.recipe.check_recipe`, wherever a module holds it) and ``torch.load``.
"""

from __future__ import annotations

import sys
from collections import Counter

import pytest
import torch
from click.testing import CliRunner

from conftest import des18_strips
from svbrdf_train.cli import cli
from svbrdf_train.recipe import checks, files
from svbrdf_train.training import step as step_module

SMOKE = ("fit", "--recipe", "ours-mix", "--size", "smoke", "-q", "--no-track", "--set", "data.count=8")


@pytest.fixture
def counted(monkeypatch):
    """Calls of the recipe reader (by file), of the checks (the recipes checked, kept alive so
    that no two share an id), of ``torch.load`` (by file), and the recipe each fit trained."""
    calls = {"read": Counter(), "checked": [], "load": Counter(), "trained": []}
    read, check, load, init = files._read_yaml, checks.check_recipe, torch.load, step_module.GanStep.__init__

    def counting_read(path):
        calls["read"][str(path.resolve())] += 1
        return read(path)

    def counting_check(recipe, where):
        calls["checked"].append(recipe)
        return check(recipe, where)

    def counting_load(f, *args, **kwargs):
        calls["load"][str(f)] += 1
        return load(f, *args, **kwargs)

    def recording_init(self, recipe, *args, **kwargs):
        calls["trained"].append(recipe)
        init(self, recipe, *args, **kwargs)

    monkeypatch.setattr(files, "_read_yaml", counting_read)
    for module in list(sys.modules.values()):  # every module that imported the function by name
        if module is not None and module.__name__.startswith("svbrdf_train"):
            if getattr(module, "check_recipe", None) is check:
                monkeypatch.setattr(module, "check_recipe", counting_check)
    monkeypatch.setattr(torch, "load", counting_load)
    monkeypatch.setattr(step_module.GanStep, "__init__", recording_init)
    return calls


def _fit(*args: str):
    result = CliRunner().invoke(cli, [*SMOKE, *args], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result


def test_a_fit_reads_each_recipe_file_once_and_checks_its_recipe_once(tmp_path, counted):
    # --data of real strips on a mix recipe: the command must know it is a mix before it builds it
    real = des18_strips(tmp_path / "real", count=4, size=64)
    _fit("--data", str(real), "--max-steps", "2", "--out", str(tmp_path / "fit"))
    assert counted["read"], "no recipe file was read"
    assert set(counted["read"].values()) == {1}, counted["read"]
    (trained,) = counted["trained"]
    assert trained.data.source == "mix" and trained.data.path == str(real)
    # by load_recipe (once, with every size of the file); the trainer does not check it again
    assert sum(recipe is trained for recipe in counted["checked"]) == 1
    assert not counted["load"]  # a new fit reads no checkpoint


def test_a_resume_reads_its_checkpoint_once_and_checks_its_recipe_once(tmp_path, counted):
    real = des18_strips(tmp_path / "real", count=4, size=64)
    out = tmp_path / "fit"
    _fit("--data", str(real), "--max-steps", "2", "--out", str(out))
    for calls in ("read", "checked", "load"):
        counted[calls].clear()
    counted["trained"].clear()
    result = CliRunner().invoke(
        cli,
        ["fit", "--resume", "--out", str(out), "--max-steps", "3", "-q", "--no-track"],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    assert counted["load"] == {str(out / "last.pt"): 1}
    assert not counted["read"]  # the checkpoint's recipe: no file
    (trained,) = counted["trained"]
    assert trained.train.max_steps == 3 and trained.data.source == "mix"
    assert len(counted["checked"]) == 1 and trained.checked  # the recipe with its new budget, once
    assert torch.load(out / "last.pt", weights_only=True)["step"] == 3
