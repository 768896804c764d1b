"""The trainer's parts on their own: checkpoints, resumable sampling, scene rows, progress, recipes."""

from __future__ import annotations

import errno
import io

import pytest
import torch

from conftest import random_svbrdf
from svbrdf_render import render, training_scene
from svbrdf_render.errors import OutputError
from svbrdf_train.errors import CheckpointError, RecipeError
from svbrdf_train.recipe import (
    list_recipes,
    load_recipe,
    parse_overrides,
    recipe_differences,
    recipe_from_dict,
    with_overrides,
)
from svbrdf_train.training.checkpoint import load_checkpoint, rng_state, save_checkpoint, set_rng_state
from svbrdf_train.training.order import From as _From
from svbrdf_train.training.progress import Progress, format_duration
from svbrdf_train.training.step import scene_rows as _scene_rows

# -- checkpoints --------------------------------------------------------------------------


def test_checkpoint_round_trip_and_summary(tmp_path):
    path = save_checkpoint(tmp_path / "last.pt", {"step": 7, "run_id": "abc", "w": torch.arange(3.0)})
    state = load_checkpoint(path)
    assert state["step"] == 7 and torch.equal(state["w"], torch.arange(3.0))
    import json

    assert json.loads((tmp_path / "last.json").read_text())["step"] == 7
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_write_that_fails_leaves_the_previous_checkpoint_whole(tmp_path, monkeypatch):
    path = save_checkpoint(tmp_path / "last.pt", {"step": 1})
    before = path.read_bytes()

    def broken_save(obj, f):
        f.write(b"half a checkpoint")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OutputError, match="no space left on the device") as e:
        save_checkpoint(path, {"step": 2})
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.json", "last.pt"]  # no temporary left


def test_foreign_and_damaged_files_are_refused_in_one_line(tmp_path):
    torch.save({"weights": torch.zeros(2)}, tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"\x00not a checkpoint")
    with pytest.raises(CheckpointError, match="format 1"):
        load_checkpoint(tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a readable") as e:
        load_checkpoint(tmp_path / "junk.pt")
    assert "\n" not in str(e.value)
    with pytest.raises(CheckpointError, match="no checkpoint there"):
        load_checkpoint(tmp_path / "missing.pt")


def test_rng_state_restores_torch_and_the_scene_sampler():
    g = torch.Generator().manual_seed(3)
    torch.manual_seed(5)
    saved = rng_state(g)
    first = torch.rand(4), torch.rand(4, generator=g)
    set_rng_state(saved, g)
    again = torch.rand(4), torch.rand(4, generator=g)
    assert all(torch.equal(a, b) for a, b in zip(first, again, strict=True))


# -- sampling and scenes ------------------------------------------------------------------


def test_resumable_sampler_starts_mid_epoch_and_stops_at_whole_steps():
    inner = list(range(100, 110))
    assert list(_From(inner, 0, 8)) == inner[:8]
    assert list(_From(inner, 6, 8)) == inner[6:8]
    assert len(_From(inner, 6, 8)) == 2


def test_scene_rows_render_as_the_rows_of_the_whole_scene():
    """Each process renders its rows of one scene drawn for the whole batch: the same pictures."""
    scene = training_scene(4, generator=torch.Generator().manual_seed(0))
    maps = random_svbrdf(4, 8)
    whole = render(maps, scene)
    part = render(maps[2:4], _scene_rows(scene, 2, 4))
    assert part.shape == (2, 9, 3, 8, 8)
    assert torch.equal(part, whole[2:4])


# -- progress -----------------------------------------------------------------------------


def test_progress_line_shows_step_losses_rate_and_eta():
    p = Progress(100, enabled=True, stream=io.StringIO())
    line = p.line(25, {"loss": 0.5}, 12.0, train_s=50.0)
    assert line.startswith("step 25/100")
    assert "loss 0.5" in line and "12.0 samples/s" in line
    assert "ETA 2m30s" in line  # 75 steps left at 2 s each
    budget = Progress(100, budget_s=60.0, stream=io.StringIO())
    assert "ETA 10s" in budget.line(25, {}, 1.0, train_s=50.0)  # the time budget ends first


def test_progress_off_a_terminal_prints_whole_lines_and_quiet_prints_none():
    out = io.StringIO()
    p = Progress(10, stream=out, every_s=0.0)
    p.update(1, {"loss": 1.0}, 5.0, 1.0)
    p.message("hello")
    assert out.getvalue().splitlines() == [p.line(1, {"loss": 1.0}, 5.0, 1.0), "hello"]
    quiet = io.StringIO()
    q = Progress(10, enabled=False, stream=quiet)
    q.update(1, {}, 1.0, 1.0, force=True)
    q.message("still said")
    assert quiet.getvalue() == "still said\n"


def test_a_fit_draws_its_progress_with_the_photo_tools_status_line():
    """One progress display: the fit's line is a StatusLine's, like the refinement bar's."""
    from svbrdf_render.plumbing import StatusLine

    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    p = Progress(10, stream=out)
    assert isinstance(p.status, StatusLine) and p.tty
    p.update(1, {"loss": 1.0}, 5.0, 1.0)
    p.message("hello")
    p.close()
    first = p.line(1, {"loss": 1.0}, 5.0, 1.0)
    assert out.getvalue() == f"\r{first}\r{' ' * len(first)}\rhello\n"


@pytest.mark.parametrize(("seconds", "text"), [(0, "0s"), (59.4, "59s"), (75, "1m15s"), (4000, "1h06m")])
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text


# -- recipe helpers -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ["ours", "radn", "multigan"])
@pytest.mark.parametrize("size", ["paper", "smoke"])
def test_recipe_survives_the_checkpoint_round_trip(name, size):
    recipe = load_recipe(name, size)
    assert recipe_from_dict(recipe.to_dict()) == recipe


def test_differences_name_the_fields_and_skip_the_ignored():
    a = load_recipe("ours", "smoke")
    b = load_recipe("ours", "smoke", {"loss.adv": 0.2, "train.max_steps": 9})
    assert recipe_differences(a, b) == ["loss.adv: 0.1 -> 0.2", "train.max_steps: 2 -> 9"]
    assert recipe_differences(a, b, ignore=["train.max_steps"]) == ["loss.adv: 0.1 -> 0.2"]


def test_with_overrides_checks_fields_like_load_recipe():
    a = load_recipe("ours", "smoke")
    assert with_overrides(a, {"train.max_steps": 5}).train.max_steps == 5
    with pytest.raises(RecipeError, match="unknown field 'max_step'"):
        with_overrides(a, {"train.max_step": 5})


def test_overrides_read_exponent_numbers_as_numbers():
    values = parse_overrides(["optim.lr=1e-4", "optim.d_lr=2E3", "train.batch=4", "data.path=run1e5"])
    assert values == {"optim.lr": 1e-4, "optim.d_lr": 2000.0, "train.batch": 4, "data.path": "run1e5"}


def test_every_listed_recipe_loads_at_every_size():
    for name in list_recipes():
        for size in ("paper", "cpu", "smoke"):
            assert load_recipe(name, size).size == size


# -- the lock on a new tracking store -------------------------------------------------------------


def test_a_new_sqlite_store_is_locked_against_other_openers_and_released(tmp_path):
    """``_store_lock`` (svbrdf_render's ``locked``) holds ``<db>.lock`` exclusively: an
    ``fcntl.flock`` on the same file, as earlier versions took it (by hand, then through filelock),
    cannot take it meanwhile, and can once it is released.
    Stores that are not SQLite files get no lock file."""
    fcntl = pytest.importorskip("fcntl")
    from svbrdf_train.tracking import _store_lock

    db = tmp_path / "new" / "mlflow.db"
    lock = db.with_name("mlflow.db.lock")
    with _store_lock(f"sqlite:///{db}"):
        assert lock.is_file()
        with open(lock, "a") as other, pytest.raises(BlockingIOError):
            fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
    with open(lock, "a") as other:
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)  # released: taken at once
        fcntl.flock(other, fcntl.LOCK_UN)
    with _store_lock((tmp_path / "runs").as_uri()), _store_lock("http://127.0.0.1:5000"):
        pass
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["mlflow.db.lock", "new"]
