"""A batch chooses its threads again before each photo (issue 47): a machine that gets busy
half-way through a batch no longer keeps threads spinning for cores another program holds."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import svbrdf_render.plumbing.machine as machine
from svbrdf_models.cli import main
from svbrdf_render import Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb


def _photos(folder: Path, n: int) -> list[str]:
    out = []
    for i, name in enumerate(["tiles", "leather", "tiles"][:n]):
        photo = render(example_material(name, 64), Scene.flash(intensity=10.0 + i)).clamp(0, 1)[0]
        out.append(str(write_image(folder / f"p{i}.png", linear_to_srgb(photo))))
    return out


@pytest.fixture
def threads_back():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_threads_follow_the_machine_getting_busy(tmp_path, monkeypatch, capsys, threads_back):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(machine, "usable_cores", lambda: 2)
    loads = iter([0.0, 2.0, 2.0])  # idle at the start, busy from the second photo on
    monkeypatch.setattr(machine, "_load", lambda: next(loads))
    applied = []  # recorded, not applied: two threads on this shared test machine would crawl
    monkeypatch.setattr(torch, "set_num_threads", applied.append)
    code = main(["predict", *_photos(tmp_path, 3), "-o", str(tmp_path / "out"), "--refine", "0", "--relit", "none"])
    assert code == 0
    err = capsys.readouterr().err
    assert "2 torch threads (2 cores" in err
    assert err.count("now 1 torch thread") == 1  # said once, when it changed
    assert applied == [2, 1, 1]  # chosen at the start, then before each later photo


def test_threads_the_user_gave_are_kept(tmp_path, monkeypatch, capsys, threads_back):
    monkeypatch.setattr(machine, "_load", lambda: pytest.fail("the load is not read when --threads is given"))
    args = ["predict", *_photos(tmp_path, 2), "-o", str(tmp_path / "out"), "--refine", "0", "--relit", "none"]
    assert main([*args, "--threads", "1"]) == 0
    assert "now " not in capsys.readouterr().err
