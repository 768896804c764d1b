"""benchmarks/generalisation.py: its arguments and the fits it plans (no fit is run)."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import load_benchmark

NAMES = (
    "0000004;PolishedMarbleFloor_01Xmetal_bumpy_squares;4X2.png",
    "0000008;PolishedMarbleFloor_01Xleather_tiles;0Xdefault.png",
    "0000012;metal_bumpy_squaresXbrick_uneven_stones;1X0.png",
    "0000028;leather_tilesXbrick_uneven_stones;0X1.png",
    "0000040;brick_uneven_stonesXleather_tiles;2X0.png",
    "0000044;PolishedMarbleFloor_01Xmetal_bumpy_squares;3Xdefault.png",
)


@pytest.fixture(scope="module")
def gen():
    return load_benchmark("generalisation")


@pytest.fixture
def folders(tmp_path):
    unseen, des18 = tmp_path / "unseen", tmp_path / "des18"
    unseen.mkdir()
    des18.mkdir()
    (unseen / "ambientcg_Rock053.png").touch()
    for name in NAMES:  # only the names are read before fitting
        (des18 / name).touch()
    return unseen, des18


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--variants", "paper,nope"], "unknown variant 'nope'"),
        (["--folds", "hold-out:"], "names no material"),
        (["--folds", "hold-out:wood+brick"], "'wood' is no known material"),
        (["--skip-fit"], "--skip-fit: no "),
    ],
)
def test_bad_arguments_exit_2_with_one_line(gen, folders, tmp_path, capsys, extra, message):
    assert gen.main([*map(str, folders), "-o", str(tmp_path / "out"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("generalisation: error: ") and message in err and "\n" not in err


def test_missing_folder_exits_2(gen, folders, tmp_path, capsys):
    assert gen.main([str(tmp_path / "none"), str(folders[1])]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_plan_one_real_fit_per_fold_on_its_training_strips(gen, folders, tmp_path, capsys):
    folds = "hold-out:brick_uneven_stones+leather_tiles;Polished,metal"
    assert gen.main([*map(str, folders), "-o", str(tmp_path / "o"), "--folds", folds, "--print"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4 + 2
    assert all(line.startswith("OMP_NUM_THREADS=1 svbrdf-train fit --recipe ") for line in lines)
    assert "--recipe ours-general" in lines[3] and "--set" not in lines[3].split("checkpoint_every=500")[1]
    real = [line for line in lines if "data.source=mix" in line]
    assert len(real) == 2 and all("--recipe ours-general" in line for line in real)
    assert "hold-out:brick_uneven_stones+leather_tiles/train" in real[0]
    assert "hold-out:PolishedMarbleFloor_01+metal_bumpy_squares/train" in real[1]


def test_comparisons_follow_the_chain(gen):
    fits = gen.plan(["paper", "resize", "resize+norm+phone"], [], Path("o"), 1.0, "cpu")
    real = gen.Fit("r", "resize+norm+phone+real 30% [f]", "ours-general", (), data=Path("t"), fold="f")
    test = gen.TestSet("t", [], [], [f.label for f in fits] + [real.label, "mean"])
    pairs = gen.comparisons(test, [*fits, real])
    assert ("resize", "paper") in pairs
    assert ("resize+norm+phone", "resize") not in pairs  # not one step: resize+norm is missing
    assert (real.label, "resize+norm+phone") in pairs and ("paper", "mean") in pairs
