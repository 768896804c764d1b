"""A material folder is old or new, never both, and never written through a link (issue 47):
the rerun of a photo swaps the whole folder in one step; a symbolic link inside ``-o`` is
refused before anything is written."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import svbrdf_render.plumbing.atomic as files
from svbrdf_models.cli import main
from svbrdf_render import Scene, render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.plumbing import replace_folder

FAST = ["--refine", "0", "--relit", "none", "--threads", "1"]


def _photo(path: Path, name: str = "tiles") -> Path:
    photo = render(example_material(name, 64), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    return write_image(path, linear_to_srgb(photo))


def test_a_link_inside_out_is_refused_and_its_target_untouched(tmp_path, capsys):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "index.html").write_text("my page\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "x").symlink_to(outside)
    code = main(["predict", str(_photo(tmp_path / "x.png")), "-o", str(out), *FAST])
    assert code == 2
    err = capsys.readouterr().err
    assert "symbolic link" in err and "Traceback" not in err
    assert sorted(p.name for p in outside.iterdir()) == ["index.html"]
    assert (outside / "index.html").read_text() == "my page\n"


def _folders(tmp_path):
    folder, stage = tmp_path / "m", tmp_path / ".m.1.tmp"
    folder.mkdir()
    stage.mkdir()
    for name, text in (("material.json", "old"), ("normal.png", "old"), ("relit.png", "old"), ("notes.txt", "mine")):
        (folder / name).write_text(text)
    for name in ("material.json", "normal.png"):
        (stage / name).write_text("new")
    return folder, stage


@pytest.mark.parametrize("exchange", [True, False], ids=["one-step swap", "two renames"])
def test_a_rerun_replaces_the_whole_folder_keeping_what_the_user_put_there(tmp_path, monkeypatch, exchange):
    if not exchange:
        monkeypatch.setattr(files, "_exchange", lambda a, b: False)
    folder, stage = _folders(tmp_path)
    replace_folder(stage, folder, keep=("material.json", "normal.png", "relit.png"))
    assert sorted(p.name for p in folder.iterdir()) == ["material.json", "normal.png", "notes.txt"]
    assert (folder / "material.json").read_text() == "new" and (folder / "notes.txt").read_text() == "mine"
    assert (stage / "material.json").read_text() == "old"  # the caller removes it


def test_an_interrupt_before_the_swap_leaves_the_old_folder_whole(tmp_path, monkeypatch):
    folder, stage = _folders(tmp_path)

    def killed(a, b):
        raise KeyboardInterrupt

    monkeypatch.setattr(files, "_exchange", killed)
    with pytest.raises(KeyboardInterrupt):
        replace_folder(stage, folder, keep=("material.json", "normal.png", "relit.png"))
    assert {p.name: p.read_text() for p in folder.iterdir()} == {
        "material.json": "old", "normal.png": "old", "relit.png": "old", "notes.txt": "mine"
    }


def test_the_swap_is_one_step_on_this_system(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "x").write_text("a")
    if not files._exchange(a, b):
        pytest.skip("no renameat2(RENAME_EXCHANGE) here: the two-rename fallback is used")
    assert (b / "x").read_text() == "a" and not (a / "x").exists()


def test_a_rerun_of_the_same_photo_gives_the_new_material_whole(tmp_path):
    photo = _photo(tmp_path / "tiles.png")
    out = tmp_path / "out"
    assert main(["predict", str(photo), "-o", str(out), *FAST]) == 0
    (out / "tiles" / "notes.txt").write_text("mine")
    first = json.loads((out / "tiles" / "material.json").read_text())
    assert main(["predict", str(photo), "-o", str(out), "--refine", "1", "--relit", "none", "--threads", "1"]) == 0
    second = json.loads((out / "tiles" / "material.json").read_text())
    assert second["refine"] != first["refine"]
    assert (out / "tiles" / "notes.txt").read_text() == "mine"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no stage left
    assert os.path.isdir(out / "tiles") and not (out / "tiles").is_symlink()


def test_a_failed_photo_does_not_poison_later_runs_into_the_folder(tmp_path, capsys):
    out = tmp_path / "out"
    bad = tmp_path / "bad.png"
    bad.write_text("not a photo")
    assert main(["predict", str(bad), "-o", str(out), *FAST]) == 2
    good = _photo(tmp_path / "tiles.png")
    capsys.readouterr()
    assert main(["predict", str(good), "-o", str(out), *FAST]) == 0  # its own photo succeeded
    err = capsys.readouterr().err
    assert not [line for line in err.splitlines() if line.startswith("bad.png")]  # this run's table only
    assert "photo(s) failed" not in err
    assert "2 photo(s) of this and earlier runs, 1 failed" in err
    _photo(bad)  # the failed photo, fixed, captured again: its entry is replaced
    assert main(["predict", str(bad), "-o", str(out), *FAST]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == 0 and summary["photos"] == 2
    assert sorted(e["name"] for e in summary["entries"]) == ["bad", "tiles"]
    assert all(len(e["model"].rsplit("@", 1)[1]) == 12 for e in summary["entries"])  # which model made each
