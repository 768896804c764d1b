"""Source materials of strips, material folds (``data folds``) and per-material averages."""

from __future__ import annotations

import re

import pytest
import torch
from click.testing import CliRunner

from conftest import random_svbrdf
from svbrdf_models.errors import DataError
from svbrdf_render import write_des18
from svbrdf_train.cli import cli
from svbrdf_train.data.real.materials import (
    fold_from_spec,
    group_samples,
    material_folds,
    material_groups,
    per_material,
)

MATERIALS = ("PolishedMarbleFloor_01", "brick_uneven_stones", "leather_tiles", "metal_bumpy_squares")


def _names() -> list[str]:
    """Every pair of the 4 materials, in both orders, as Des18 names (12 strips)."""
    out = []
    for a in MATERIALS:
        for b in MATERIALS:
            if a != b:
                out.append(f"{4 * len(out):07d};{a}X{b};{len(out) % 5}Xdefault.png")
    return out


@pytest.fixture
def strips(tmp_path):
    """Tiny real strips with Des18 names, in a folder."""
    folder = tmp_path / "des18"
    folder.mkdir()
    pairs: dict = {}
    for name in _names():  # one strip of each of the 6 pairs
        pairs.setdefault(material_groups(name), name)
    for i, name in enumerate(pairs.values()):
        photo = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(i))
        write_des18(folder / name, photo, random_svbrdf(1, 16, seed=i))
    return folder


def _run(*args):
    return CliRunner().invoke(cli, ["data", *map(str, args)])


def test_groups_of_des18_names_and_of_other_files(tmp_path):
    name = "0000004;PolishedMarbleFloor_01Xmetal_bumpy_squares;4X2.png"
    assert material_groups(name) == ("PolishedMarbleFloor_01", "metal_bumpy_squares")
    assert material_groups(tmp_path / "0000016;brick_uneven_stonesXmetal_bumpy_squares;2X0.png") == (
        "brick_uneven_stones",
        "metal_bumpy_squares",
    )  # sorted, whatever the order in the name
    assert material_groups("0000001;leather_tilesXleather_tiles;0X1.png") == ("leather_tiles",)
    assert material_groups("ambientcg_Bark014.png") == ("ambientcg_Bark014",)
    assert material_groups("0000000;a;b.png") == ("0000000;a;b",)  # no pair: the file is the material
    with pytest.raises(DataError, match=r"ambientcg_Bark014\.png: not a Des18 strip name"):
        material_groups(tmp_path / "ambientcg_Bark014.png", strict=True)


def test_group_samples_auto_falls_back_to_files():
    names = _names()[:3]
    assert group_samples(names)[0] == "des18"
    mode, groups = group_samples([*names, "ambientcg_Rock053.png"])
    assert mode == "file" and groups[-1] == ("ambientcg_Rock053",) and len(set(groups)) == 4
    with pytest.raises(DataError, match="ambientcg_Rock053.png"):
        group_samples([*names, "ambientcg_Rock053.png"], "des18")


def test_six_folds_keep_judged_materials_out_of_training_and_judge_every_strip_once():
    names = _names()
    folds = material_folds(names)
    assert len(folds) == 6
    assert {f.name for f in folds} >= {"hold-out:brick_uneven_stones+leather_tiles",
                                       "hold-out:PolishedMarbleFloor_01+metal_bumpy_squares"}  # fmt: skip
    judged = []
    for fold in folds:
        train_materials = {m for f in fold.train for m in material_groups(f)}
        for f in fold.judge:
            assert not set(material_groups(f)) & train_materials, (fold.name, f)
            assert set(material_groups(f)) <= set(fold.held_out)
        judged += fold.judge
    assert sorted(judged) == sorted(names)  # every strip judged exactly once


def test_spec_picks_one_fold_by_prefixes():
    fold = fold_from_spec(_names(), "BRICK, leath")
    assert fold.name == "hold-out:brick_uneven_stones+leather_tiles"
    assert len(fold.judge) == 2 and len(fold.train) == 2


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        ("wood", "'wood' is no known material"),
        ("", "names no material"),
        ("brick", "leaves nothing to judge"),
        ("brick,leather,metal", "leaves nothing to train on"),
    ],
)
def test_bad_specs_say_what_and_list_the_materials(spec, needle):
    with pytest.raises(DataError) as e:
        fold_from_spec(_names(), spec, where="des18-dev")
    assert needle in str(e.value) and "des18-dev" in str(e.value)
    assert all(m in str(e.value) for m in MATERIALS)


def test_an_ambiguous_prefix_names_both_candidates():
    names = ["0;brickAXbrickB;0X0.png", "1;brickAXstone;0X0.png", "2;brickBXwood;0X0.png", "3;stoneXwood;0X0.png"]
    with pytest.raises(DataError, match="could be brickA or brickB"):
        fold_from_spec(names, "brick")


def test_per_material_weighs_every_material_alike():
    rows = [("0;aXb;0X0.png", {"rmse": 1.0}), ("1;aXb;0X0.png", {"rmse": 1.0}), ("2;aXb;0X0.png", {"rmse": 1.0}),
            ("3;cXc;0X0.png", {"rmse": 4.0})]  # fmt: skip
    pm = per_material(rows)
    assert pm.materials == {"a": {"rmse": 1.0}, "b": {"rmse": 1.0}, "c": {"rmse": 4.0}}
    assert pm.counts == {"a": 3, "b": 3, "c": 1} and pm.strips == 4
    assert pm.mean["rmse"] == pytest.approx(2.0)  # per strip it would be 1.75
    assert pm.values("rmse") == [1.0, 1.0, 4.0]
    assert per_material([(("x",), {"k": 2.0}), (("x", "y"), {"k": 4.0})]).materials == {
        "x": {"k": 3.0}, "y": {"k": 4.0}}  # fmt: skip


def test_data_folds_writes_links_and_a_table(strips, tmp_path):
    out = tmp_path / "folds"
    result = _run("folds", strips, "--out", out)
    assert result.exit_code == 0, result.output
    assert f"6 strips of 4 materials in {strips}" in result.stdout
    rows = [line for line in result.stdout.splitlines() if line.startswith("hold-out:")]
    assert len(rows) == 6 and "6 judged strips in all" in result.stdout
    fold = out / "hold-out:brick_uneven_stones+leather_tiles"
    judge, train = sorted((fold / "judge").iterdir()), sorted((fold / "train").iterdir())
    assert judge and train and all(p.is_symlink() and p.resolve().parent == strips.resolve() for p in judge + train)
    assert re.search(r"hold-out:brick_uneven_stones\+leather_tiles\s+%d\s" % len(train), result.stdout)
    # Read back as a Des18 folder, as fit --data and svbrdf-bench --test-data do.
    from svbrdf_train.data.real.des18 import Des18Folder

    assert len(Des18Folder(fold / "judge", "test", crop=None)) == len(judge)
    again = _run("folds", strips, "--out", out, "--hold-out", "brick,leather")  # links replaced
    assert again.exit_code == 0, again.output
    assert sorted((fold / "judge").iterdir()) == judge


@pytest.mark.parametrize("spec", ["wood", "brick"])
def test_data_folds_bad_spec_is_one_line_exit_2(strips, tmp_path, spec):
    result = _run("folds", strips, "--out", tmp_path / "folds", "--hold-out", spec)
    assert result.exit_code == 2
    assert result.stderr.startswith("svbrdf-train: error: --hold-out") and result.stderr.count("\n") == 1
    assert "brick_uneven_stones" in result.stderr and "Traceback" not in result.output


def test_data_folds_refuses_names_that_are_not_des18(tmp_path):
    folder = tmp_path / "other"
    folder.mkdir()
    write_des18(folder / "ambientcg_Bark014.png", torch.rand(1, 3, 16, 16), random_svbrdf(1, 16, seed=0))
    result = _run("folds", folder, "--out", tmp_path / "folds")
    assert result.exit_code == 2 and "ambientcg_Bark014.png: not a Des18 strip name" in result.stderr


@pytest.mark.data
def test_the_real_des18_folder_gives_six_folds_judging_each_strip_once(shared_data):
    from svbrdf_train.data.real.materials import strip_files

    files = strip_files(shared_data / "des18-dev")
    folds = material_folds(files)
    assert len(folds) == 6 and sorted(f for fold in folds for f in fold.judge) == sorted(files)
