"""Map-only material strips (``data.source: materials``): windows, turns and photos drawn per
sample, normals turned with the pixels, albedos kept physical, folds by material, strip shards,
and one-line refusals of strips that are not strips."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from click.testing import CliRunner

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDF, encode_normal, safe_normalize
from svbrdf_render.formats.mapfiles import write_image
from svbrdf_train.cli import cli
from svbrdf_train.data.fitdata import open_materials
from svbrdf_train.data.real.des18 import dihedral_image
from svbrdf_train.data.real.strip_bank import MaterialBank, read_strip_shard, resize_bank, write_strip_shard
from svbrdf_train.data.real.strips import ALBEDO_CEILING, CROP_SIDE, MaterialStrips, fold_split
from svbrdf_train.data.simulated_photo import PhotoSettings


def _height(size: int, seed: int) -> torch.Tensor:
    """A smooth random height field ``(size, size)``."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.randn(1, 1, 6, 6, generator=g)
    return F.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=True)[0, 0] * 20 / size


def _normals_of(h: torch.Tensor) -> torch.Tensor:
    """OpenGL normals of a height field: x right, y up (rows grow downwards)."""
    dx = torch.gradient(h, dim=1)[0]
    drow = torch.gradient(h, dim=0)[0]
    return safe_normalize(torch.stack([-dx, drow, torch.ones_like(h)]), dim=0)


def write_strip(path, size=64, seed=0, *, diffuse=None, specular=0.04, normal=None, roughness=None):
    """One strip PNG: normal | diffuse | roughness | specular."""
    g = torch.Generator().manual_seed(seed)
    n = _normals_of(_height(size, seed)) if normal is None else normal
    d = (
        0.1 + 0.6 * torch.rand(3, size, size, generator=g)
        if diffuse is None
        else diffuse.expand(3, size, size)
    )
    r = (0.2 + 0.6 * torch.rand(1, size, size, generator=g) if roughness is None else roughness).expand(
        3, size, size
    )
    s = torch.full((3, size, size), specular)
    write_image(path, torch.cat([encode_normal(n), d, r, s], dim=2), bits=8)
    return path


@pytest.fixture
def strips(tmp_path):
    folder = tmp_path / "strips"
    folder.mkdir()
    for i, name in enumerate(["bark", "brick", "fabric", "metal", "stone", "wood"]):
        write_strip(folder / f"{name}.png", seed=i)
    return folder


def _data(folder, **kw):
    kw.setdefault("photo", PhotoSettings.preset("phone"))
    return MaterialStrips(MaterialBank.open(folder), 60, 32, **kw)


def test_a_sample_is_a_photo_and_its_maps_at_the_resolution(strips):
    data = _data(strips)
    s = data[7]
    assert s["input"].shape == (3, 32, 32) and s["maps"].shape == (10, 32, 32)
    assert s["name"] == "strip:brick"  # sample i shows material i % 6
    maps = SVBRDF.unpack(s["maps"][None])  # validates ranges and unit normals
    assert torch.allclose(maps.normal.norm(dim=1), torch.ones(1, 32, 32), atol=1e-5)
    assert 0 <= float(s["input"].min()) and float(s["input"].max()) <= 1 and float(s["input"].mean()) > 0.01


def test_the_draws_follow_seed_epoch_and_index(strips):
    a, b = _data(strips), _data(strips)
    assert torch.equal(a[3]["input"], b[3]["input"]) and torch.equal(a[3]["maps"], b[3]["maps"])
    b.set_epoch(1)
    assert not torch.equal(a[3]["maps"], b[3]["maps"])
    assert not torch.equal(_data(strips, seed=5)[3]["input"], a[3]["input"])


def test_windows_cover_a_quarter_to_the_whole_material(strips):
    data = MaterialStrips(MaterialBank.open(strips), 600, 16, photo=PhotoSettings())
    shares = torch.tensor([data.placement(i).side / 64 for i in range(600)])
    assert float(shares.min()) >= CROP_SIDE[0] - 1 / 64 and float(shares.max()) <= 1.0
    assert float(shares.min()) < 0.55 and float(shares.max()) > 0.95  # both ends are reached
    assert len({data.placement(i).dihedral for i in range(600)}) == 8


def test_normals_turn_and_mirror_with_the_pixels(tmp_path):
    """The sample's normals still match the gradient of the height field that was cut, turned
    and mirrored with it: a turn that moved the pixels but not the vectors would not."""
    folder = tmp_path / "one"
    folder.mkdir()
    size = 64
    h = _height(size, seed=3)
    write_strip(folder / "relief.png", size=size, normal=_normals_of(h))
    data = MaterialStrips(MaterialBank.open(folder), 40, size, photo=PhotoSettings())
    seen = set()
    for i in range(40):
        c = data.placement(i)
        if c.side != size or c.dihedral in seen:  # whole tiles: the height field needs no resizing
            continue
        seen.add(c.dihedral)
        turned = dihedral_image(h[None], c.dihedral)[0]
        want = _normals_of(turned)
        got = SVBRDF.unpack(data[i]["maps"][None]).normal[0]
        for axis in (0, 1):
            corr = np.corrcoef(got[axis].flatten().numpy(), want[axis].flatten().numpy())[0, 1]
            assert corr > 0.9, (c.dihedral, axis, corr)
    assert len(seen) >= 4, seen


def test_albedo_scaling_stays_physical_and_leaves_specular(tmp_path):
    folder = tmp_path / "bright"
    folder.mkdir()
    write_strip(folder / "white.png", diffuse=torch.full((3, 1, 1), 0.9), specular=0.04)
    write_strip(folder / "gold.png", seed=1, diffuse=torch.full((3, 1, 1), 0.0), specular=0.8)
    data = MaterialStrips(MaterialBank.open(folder), 200, 32, photo=PhotoSettings())
    factors = [data.placement(i).albedo for i in range(200)]
    assert min(factors) < 0.85 and max(factors) > 1.15  # both darker and brighter ones are drawn
    for i in range(0, 200, 7):
        m = SVBRDF.unpack(data[i]["maps"][None])
        assert float(m.diffuse.max()) <= max(ALBEDO_CEILING, 0.9) + 1e-4 and float(m.diffuse.min()) >= 0
        want = 0.8 if i % 2 == 0 else 0.04  # gold (sorted first) keeps its F0, white its 0.04
        assert torch.allclose(m.specular, torch.full_like(m.specular, round(want * 255) / 255), atol=1e-5)


def test_validation_samples_are_whole_tiles_under_fixed_photos(strips):
    a = MaterialStrips(MaterialBank.open(strips), 6, 32, augment=False, photo=PhotoSettings())
    assert {a.placement(i) for i in range(6)} == {a.placement(i)._replace(material=i) for i in range(6)}
    assert all(a.placement(i).side == 64 and a.placement(i).dihedral == 0 for i in range(6))
    first = a[2]["input"]
    a.set_epoch(9)
    assert torch.equal(a[2]["input"], first)


def test_folds_split_by_material_and_never_overlap(strips):
    names = MaterialBank.open(strips).names
    held = [fold_split(names, f"{k}/3")[1] for k in (1, 2, 3) if _nonempty(names, k, 3)]
    assert sorted(m for h in held for m in h) == sorted(set(m for h in held for m in h))
    train, out = fold_split(names, "bri,wood")
    assert out == ["brick", "wood"] and set(train) == set(names) - set(out)
    # A new material moves no other between folds.
    bigger = [*names, "zinc"]
    for k in (1, 2, 3):
        if _nonempty(names, k, 3) and _nonempty(bigger, k, 3):
            assert set(fold_split(names, f"{k}/3")[1]) <= set(fold_split(bigger, f"{k}/3")[1])


def _nonempty(names, k, n):
    try:
        fold_split(names, f"{k}/{n}")
        return True
    except DataError:
        return False


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        ("oak", "'oak' is no known material"),
        ("b", "could be"),
        ("0/5", "1 <= k <= n"),
        ("9/100", "names no material"),
    ],
)
def test_a_fold_that_names_no_material_is_refused(strips, spec, needle):
    names = MaterialBank.open(strips).names
    with pytest.raises(DataError, match=needle):
        fold_split(names, spec, "strips/")


def test_a_strip_shard_holds_the_strips_decoded(strips, tmp_path):
    bank = MaterialBank.open(strips)
    path = write_strip_shard(bank, tmp_path / "s.h5")
    back = read_strip_shard(path)
    assert back.names == bank.names and all(
        np.array_equal(a, b) for a, b in zip(back.maps, bank.maps, strict=True)
    )
    small = read_strip_shard(write_strip_shard(resize_bank(bank, 32), tmp_path / "s32.h5"))
    assert small.tile == 32
    # The shard feeds the same samples as the folder it was made from.
    assert torch.equal(MaterialStrips(back, 6, 32)[4]["maps"], MaterialStrips(bank, 6, 32)[4]["maps"])
    with pytest.raises(DataError, match="already exists"):
        write_strip_shard(bank, path)


def test_strip_folders_are_materials_with_ground_truth(strips):
    data, what = open_materials(strips, "data.real_validation")
    assert len(data) == 6 and "material strips" in what
    assert data[0]["maps"].shape == (10, 64, 64)


def _refused(args, *needles):
    result = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("svbrdf-train: error: ") and result.stderr.count("\n") == 1, result.stderr
    for needle in needles:
        assert needle in result.stderr, (needle, result.stderr)


def test_bad_strips_are_refused_in_one_line_naming_the_file(tmp_path):
    folder = tmp_path / "bad"
    folder.mkdir()
    write_image(folder / "five.png", torch.rand(3, 16, 80))
    _refused(["data", "strips", str(folder), "--folds", "3"], "five.png", "not four square tiles")
    (folder / "five.png").unlink()
    flat = torch.full((3, 16, 16), 0.5)  # decodes to zero-length normals
    write_image(folder / "grey.png", torch.cat([flat, flat, flat, flat], dim=2))
    _refused(["data", "strips", str(folder), "--folds", "3"], "grey.png", "no unit vector field")
    (folder / "grey.png").unlink()
    _refused(["data", "strips", str(folder), "--folds", "3"], str(folder), "no material strips")


def test_a_fit_on_strips_validates_the_held_out_fold(strips, tmp_path):
    from svbrdf_train.recipe import load_recipe
    from svbrdf_train.training.trainer import FitOptions, fit

    recipe = load_recipe(
        "ours-materials",
        "smoke",
        overrides={
            "data.path": str(strips),
            "data.mix": [
                {"source": "procedural", "weight": 1},
                {"source": "materials", "weight": 1, "fold": "fabric"},
            ],
        },
    )
    result = fit(recipe, FitOptions(out=tmp_path / "out", track=False, progress=False))
    assert result.status == "FINISHED"
    assert {f"val_fold/rmse/{m}" for m in ("normal", "diffuse", "render")} <= set(result.metrics)
    assert all(np.isfinite(v) for v in result.metrics.values())


def test_the_held_out_fold_is_photographed_under_its_entry_s_capture(strips):
    from svbrdf_train.data.fitdata import fold_validation_set
    from svbrdf_train.recipe import load_recipe

    def fold_photo(capture):
        entry = {"source": "materials", "weight": 1, "fold": "fabric", **({"capture": capture} if capture else {})}
        recipe = load_recipe("ours-materials", "smoke", overrides={
            "data.path": str(strips), "data.capture": "phone",
            "data.mix": [{"source": "procedural", "weight": 1}, entry]})  # fmt: skip
        held, _ = fold_validation_set(recipe.data, recipe.train.resolution)
        return held.photo

    assert fold_photo(None) == PhotoSettings.preset("phone")
    assert fold_photo("handheld") == PhotoSettings.preset("handheld")


def test_init_takes_the_shipped_model_file():
    """``fit --init pretrained``: the shipped generator, its steps and time, no discriminator;
    it matches ours-materials at the cpu size, the recipe meant to go on from it."""
    from svbrdf_models import load_model
    from svbrdf_train.recipe import load_recipe
    from svbrdf_train.training.init import check_generator, load_init

    init = load_init("pretrained")
    shipped = load_model("pretrained")
    assert init.discriminator is None and init.step == shipped.steps > 0
    state = shipped.generator.state_dict()
    assert set(init.generator) == set(state) and all(torch.equal(init.generator[k], state[k]) for k in state)
    check_generator(init, load_recipe("ours-materials", "cpu"))  # raises on another network


def test_compare_sets_a_training_mix_with_strips_against_real(strips):
    result = CliRunner().invoke(
        cli,
        [
            "data",
            "compare",
            str(strips),
            "-n",
            "4",
            "-r",
            "32",
            "--strips",
            str(strips),
            "--strip-share",
            "0.5",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "50% of them strips" in result.output and "| specular level |" in result.output
    alone = CliRunner().invoke(cli, ["data", "compare", str(strips), "-n", "4", "--strip-share", "0.5"])
    assert alone.exit_code == 2 and "give --strips DIR with it" in alone.stderr, alone.output


@pytest.mark.parametrize(
    ("fold", "needles"),
    [("1/100", ["fold '1/100'", "names no material"]), ("oak", ["'oak' is no known material", "strips"])],
)
def test_fit_refuses_a_fold_that_names_no_material(strips, tmp_path, fold, needles):
    mix = f"[{{source: materials, weight: 1, fold: '{fold}'}}]"
    args = ["fit", "-q", "--no-track", "--recipe", "ours-materials", "--size", "smoke", "--data", str(strips)]
    _refused([*args, "--out", str(tmp_path / "out"), "--set", f"data.mix={mix}"], *needles)


def test_fit_refuses_a_folder_without_strips(tmp_path):
    (tmp_path / "empty").mkdir()
    args = ["fit", "-q", "--no-track", "--recipe", "ours-materials", "--size", "smoke"]
    _refused(
        [*args, "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "out")],
        "empty",
        "no material strips",
    )


@pytest.mark.slow
def test_a_fit_on_strips_stopped_and_resumed_ends_bitwise_as_one_that_never_stopped(strips, tmp_path):
    """Every window, turn and photo follows from (seed, epoch, index): a resumed fit sees the
    very samples the uninterrupted one saw."""
    from conftest import run_cli
    from svbrdf_train.training.checkpoint import load_checkpoint

    base = (
        "fit", "--recipe", "ours-materials", "--size", "smoke", "-q", "--no-track", "--data", str(strips),
        "--set", "data.count=8", "--set", "train.epochs=4", "--set", "train.checkpoint_every=4",
        "--set", "optim.g_steps_per_d=2",
    )  # fmt: skip
    whole = run_cli(*base, "--max-steps", "12", "--out", "whole", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    cut = run_cli(*base, "--max-steps", "6", "--out", "cut", cwd=tmp_path)
    assert cut.returncode == 0, cut.stderr
    resumed = run_cli(
        "fit", "--out", "cut", "--resume", "--max-steps", "12", "-q", "--no-track", cwd=tmp_path
    )
    assert resumed.returncode == 0, resumed.stderr
    a, b = load_checkpoint(tmp_path / "whole" / "last.pt"), load_checkpoint(tmp_path / "cut" / "last.pt")
    assert a["step"] == b["step"] == 12
    for part in ("generator", "discriminator"):
        for name, tensor in a[part].items():
            assert torch.equal(tensor, b[part][name]), (part, name)


# -- the batched path of data.generate: device ------------------------------------------------


def test_the_batched_path_gives_the_cpu_paths_whole_tiles_under_every_turn(strips):
    """Windows of the resolution's size are read at pixel centres: the CPU path's values (to
    float16's rounding), under each of the 8 turns and mirrors, normals turned alike."""
    from svbrdf_train.data.real.strip_batch import strip_batch

    data = MaterialStrips(MaterialBank.open(strips), 40, 64, photo=PhotoSettings())
    indices = list(range(40))
    assert len({data.placement(i).dihedral for i in indices}) == 8
    cpu = torch.stack([data[i]["maps"] for i in indices])
    batched = strip_batch(data, indices, "cpu")
    assert batched["maps"].shape == cpu.shape and batched["name"] == [data[i]["name"] for i in indices]
    assert float((batched["maps"] - cpu).abs().max()) < 2e-3


def test_the_batched_path_resamples_windows_as_the_cpu_path_does_on_average(tmp_path):
    """Resized windows: bilinear reads of a mip level, averaged 2x2, against the exact area
    filter: the same means, a small difference per pixel on smooth maps."""
    from svbrdf_train.data.real.strip_batch import strip_batch

    folder = tmp_path / "smooth"
    folder.mkdir()
    for i in range(3):
        smooth = 0.2 + 0.6 * torch.sigmoid(3 * _height(64, seed=10 + i))
        write_strip(
            folder / f"m{i}.png", seed=i, diffuse=smooth.expand(3, -1, -1), roughness=smooth.flip(0)[None]
        )
    data = MaterialStrips(MaterialBank.open(folder), 30, 32, photo=PhotoSettings())
    indices = [i for i in range(30) if data.placement(i).side != 32]
    cpu = torch.stack([data[i]["maps"] for i in indices])
    batched = strip_batch(data, indices, "cpu")["maps"]
    for a, b in ((0, 3), (3, 6), (6, 7), (7, 10)):
        assert float((batched[:, a:b] - cpu[:, a:b]).square().mean().sqrt()) < 0.02, (a, b)
        assert abs(float(batched[:, a:b].mean() - cpu[:, a:b].mean())) < 2e-3, (a, b)
    batched_photos = strip_batch(data, indices, "cpu")["input"]
    assert batched_photos.shape == (len(indices), 3, 32, 32) and float(batched_photos.max()) <= 1


@pytest.mark.slow
def test_the_gpu_session_script_dry_runs_on_the_cpu(strips, tmp_path):
    """benchmarks/gpu_session.sh at the smoke size on the CPU: the option ladder measured, an
    ablation under the best options, the training recipe trained and its model file written."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "out"
    env = {**os.environ, "OUT": str(out), "DEVICE": "cpu", "SIZE": "smoke", "BUDGET": "1.6",
           "PYTHON": sys.executable, "STRIPS": str(strips), "OMP_NUM_THREADS": "1"}  # fmt: skip
    args = [
        "--steps",
        "1",
        "--rungs",
        "2",
        "--recipes",
        "no-attn",
        "--train-share",
        "0.3",
        "--train-size",
        "smoke",
    ]
    done = subprocess.run(["bash", str(repo / "benchmarks" / "gpu_session.sh"), *args], env=env, cwd=repo,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((out / "gpu_session.json").read_text())
    measured = [r for r in report["rows"] if "samples_s" in r]
    assert [r["option"] for r in report["rows"][:2]] == ["device batches", "+ channels_last"]
    assert all(r["samples_s"] > 0 for r in measured) and len(measured) >= 2
    assert report["trained"]["exit"] == 0 and (out / report["trained"]["model"]).is_file()
    assert "| ours | device batches |" in (out / "gpu_session.md").read_text()
