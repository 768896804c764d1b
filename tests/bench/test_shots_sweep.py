"""benchmarks/shots_sweep.py (issue 44's study of how several shots are refined): a setting
with no keys is the capture as shipped, so that the sweep's reference row is what users get;
each key changes what it names and nothing else; a bad setting is refused naming it; photos an
earlier run simulated are read back with the same draws, not made again."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def sweep():
    return load_benchmark("shots_sweep")


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_a_setting_without_keys_refines_as_the_capture_ships(sweep, k):
    from svbrdf_models.capture.shots import refine_settings

    assert sweep.settings_for(sweep.parse_setting("kept")[1])(k) == refine_settings(k)


def test_each_key_changes_what_it_names(sweep):
    from svbrdf_render import RefineSettings

    single = RefineSettings()
    name, values = sweep.parse_setting("mix:prior=0.5,prior_specular=1,coarse=8,lr=0.02,steps=300")
    assert name == "mix" and values["steps"] == 300
    got = sweep.settings_for(values)(3)
    assert got.prior == {m: w * (1.0 if m == "specular" else 0.5) for m, w in single.prior.items()}
    assert (got.coarse, got.lr) == (8, 0.02)
    assert dataclasses.replace(got, prior=single.prior, coarse=single.coarse, lr=single.lr) == single


@pytest.mark.parametrize(
    ("text", "says"),
    [(":steps=3", "needs a name"), ("a:stpes=3", "unknown key 'stpes'"), ("a:prior=half", "prior must be a number")],
)
def test_a_bad_setting_is_refused_naming_it(sweep, text, says):
    with pytest.raises(argparse.ArgumentTypeError, match=says):
        sweep.parse_setting(text)


def test_photos_of_an_earlier_run_are_read_back_with_the_same_draws(sweep, tmp_path, monkeypatch):
    from svbrdf_render.examples import example_material

    truth = example_material("leather", 32)
    fresh = sweep.bench.simulate(truth, tmp_path, 4, 96, 2)
    made = {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*.jpg")}
    assert sorted(made) == ["card.jpg", "shot1.jpg", "shot2.jpg", "today.jpg"]

    def refuse(*args, **kwargs):
        raise AssertionError("a photo was made again")

    monkeypatch.setattr(sweep.bench.sim, "make_photo", refuse)
    again = sweep.cached(sweep.bench.simulate)(truth, tmp_path, 4, 96, 2)
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*.jpg")} == made
    today, card, frames = fresh[:3]
    assert np.allclose(again[0].camera, today.camera) and np.allclose(again[1].flash, card.flash)
    assert all(np.allclose(a.flash, b.flash) and a.intensity == b.intensity for a, b in zip(again[2], frames))


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["{empty}", "--set", "a"], "no Des18-layout strips (*.png) there"),
        (["{empty}/missing", "--set", "a"], "no Des18-layout strips (*.png) there"),
        (["{empty}", "--set", "a", "--shots", "3,x"], "expected shot counts"),
        (["{empty}", "--set", "a", "--shots", "0"], "expected shot counts"),
    ],
)
def test_a_bad_command_line_is_refused_in_one_line_before_anything_is_written(sweep, tmp_path, capsys, args, says):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as stop:
        sweep.main([a.format(empty=empty) for a in args] + ["--out", str(out)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert says in err[-1] and "Traceback" not in "\n".join(err)
    assert not out.exists()
