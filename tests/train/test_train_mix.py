"""Several sources in one fit (``data.source: mix``) and fine-tuning from trained weights
(``fit --init``): the draws follow the weights and the seed, a mixed fit resumes bit for bit,
and what cannot work is refused in one line with exit code 2."""

from __future__ import annotations

import math

import pytest
import torch
from test_train_fit_cli import _assert_refused
from test_train_fit_cli import _fit as _cli

from conftest import des18_strips, run_cli
from svbrdf_train.data import Des18Folder, PhotoSettings, ProceduralMaterials
from svbrdf_train.data.fitdata import Mixture, build_datasets
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.trainer import FitOptions, fit


class _Numbers(torch.utils.data.Dataset):
    def __init__(self, n, tag):
        self.n, self.tag = n, tag

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        return (self.tag, i)


def test_each_sample_comes_from_a_source_with_its_weight():
    mix = Mixture([_Numbers(5, "a"), _Numbers(1000, "b")], [3.0, 1.0], count=4000, seed=0)
    counts = torch.bincount(mix.which, minlength=2).tolist()
    expected = 4000 * 0.75
    assert abs(counts[0] - expected) < 4 * math.sqrt(4000 * 0.75 * 0.25), counts
    # The few samples of the small source are walked through evenly: 600 passes over 5.
    seen = torch.bincount(torch.tensor([mix[k][1] for k in range(4000) if mix[k][0] == "a"]))
    assert seen.max() - seen.min() <= 1


def test_the_draws_follow_the_seed_and_the_epoch():
    def draws(seed, epoch):
        mix = Mixture([_Numbers(7, "a"), _Numbers(9, "b")], [1.0, 1.0], count=64, seed=seed)
        mix.set_epoch(epoch)
        return [mix[k] for k in range(64)]

    assert draws(0, 3) == draws(0, 3)
    assert draws(0, 3) != draws(0, 4)
    assert draws(1, 3) != draws(0, 3)


def test_a_real_strip_met_twice_in_an_epoch_is_cropped_anew(tmp_path):
    real = Des18Folder(des18_strips(tmp_path / "real", count=1, size=64), "train", crop=32)
    mix = Mixture([real], [1.0], count=6, seed=0)
    crops = [mix[k]["input"] for k in range(6)]
    assert len({c.sum().item() for c in crops}) > 1, "every pass over the strip drew the same crop"


def test_a_mix_recipe_builds_both_sources_and_their_validation(tmp_path):
    real = des18_strips(tmp_path / "real", count=4, size=64)
    recipe = load_recipe("ours-mix", "smoke", {"data.path": str(real), "data.count": 16})
    train, val = build_datasets(recipe)
    assert isinstance(train, Mixture) and len(train) == 16
    kinds = {type(s.dataset if hasattr(s, "dataset") else s).__name__ for s in train.sources}
    assert kinds == {"ProceduralMaterials", "Des18Folder"}
    assert len(val) == 2 + 2  # data.validation procedural materials + the real entry's 2 strips
    sample = train[0]
    assert sample["input"].shape == (3, 32, 32) and sample["maps"].shape == (10, 32, 32)


@pytest.mark.parametrize(
    ("mix", "needles"),
    [
        ("[{source: procedural, weight: 0}]", ["mix[0].weight must be a positive number", "got 0"]),
        ("[{source: procedural, weight: -1}]", ["mix[0].weight", "got -1"]),
        ("[{source: procedural, weight: .nan}]", ["mix[0].weight"]),
        ("[{source: procedural}]", ["mix[0].weight", "got None"]),
        ("[{source: procedural, weight: 1}, {source: photos, weight: 1}]", ["mix[1].source", "photos"]),
        ("[{source: procedural, weight: 1, wieght: 2}]", ["unknown key 'wieght'", "'weight'"]),
        ("[]", ["needs data.mix"]),
        ("[{source: procedural, weight: 1, capture: phnoe}]", ["mix[0].capture must be one of", "'phnoe'"]),
        ("[{source: des18, weight: 1, capture: phone}]", ["mix[0].capture", "bring their own photos"]),
    ],
)
def test_bad_mixes_are_refused_in_one_line(tmp_path, mix, needles):
    result = _cli(tmp_path, "--recipe", "ours-mix", "--size", "smoke", "--set", f"data.mix={mix}")
    _assert_refused(result, *needles)


def test_missing_or_empty_sources_name_the_entry(tmp_path):
    _assert_refused(
        _cli(tmp_path, "--recipe", "ours-mix", "--size", "smoke"), "data.mix[1] (des18)", "needs a path"
    )
    (tmp_path / "empty").mkdir()
    _assert_refused(
        _cli(tmp_path, "--recipe", "ours-mix", "--size", "smoke", "--data", str(tmp_path / "empty")),
        "data.mix[1] (des18)",
        "no Des18 strips",
    )
    _assert_refused(
        _cli(
            tmp_path,
            "--recipe",
            "ours-mix",
            "--size",
            "smoke",
            "--set",
            f"data.mix=[{{source: shards, weight: 1, path: {tmp_path / 'nothing.h5'}}}]",
        ),
        "data.mix[0] (shards)",
        "nothing.h5",
    )
    _assert_refused(
        _cli(
            tmp_path,
            "--recipe",
            "ours",
            "--size",
            "smoke",
            "--set",
            "data.mix=[{source: procedural, weight: 1}]",
        ),
        "set data.source=mix",
    )


def test_data_given_to_a_mix_recipe_fills_its_real_entry(tmp_path):
    real = des18_strips(tmp_path / "real", count=4, size=64)
    result = _cli(tmp_path, "--recipe", "ours-mix", "--size", "smoke", "--data", str(real))
    assert result.exit_code == 0, result.output
    recipe = load_checkpoint(tmp_path / "out" / "last.pt")["recipe"]
    assert recipe["data"]["source"] == "mix" and recipe["data"]["path"] == str(real)


MIXED = (
    "fit", "--recipe", "ours-mix", "--size", "smoke", "-q", "--experiment", "tests-mix",
    "--set", "data.count=8", "--set", "train.epochs=4", "--max-steps", "12",
    "--set", "train.checkpoint_every=4", "--set", "optim.g_steps_per_d=2",
)  # fmt: skip


@pytest.mark.slow
def test_a_mixed_fit_stopped_and_resumed_ends_bitwise_as_one_that_never_stopped(tmp_path):
    real = des18_strips(tmp_path / "real", count=4, size=64)
    data = ("--data", str(real))
    one = {"OMP_NUM_THREADS": "1"}  # each run would pick its threads by the load it meets: sums differ
    whole = run_cli(*MIXED, *data, "--out", "whole", cwd=tmp_path, env=one)
    assert whole.returncode == 0, whole.stderr
    first = run_cli(*MIXED, *data, "--out", "cut", "--max-steps", "6", cwd=tmp_path, env=one)
    assert first.returncode == 0, first.stderr
    assert load_checkpoint(tmp_path / "cut" / "last.pt")["step"] == 6  # mid-epoch: 4 steps an epoch
    resumed = run_cli("fit", "--out", "cut", "--resume", "--max-steps", "12", "-q", cwd=tmp_path, env=one)
    assert resumed.returncode == 0, resumed.stderr
    a = load_checkpoint(tmp_path / "whole" / "last.pt")
    b = load_checkpoint(tmp_path / "cut" / "last.pt")
    assert a["step"] == b["step"] == 12
    for part in ("generator", "discriminator"):
        for name, tensor in a[part].items():
            assert torch.equal(tensor, b[part][name]), (part, name)


# -- fine-tuning ------------------------------------------------------------------------------


def _smoke_fit(tmp_path, name, recipe="ours", init=None, **overrides):
    result = fit(
        load_recipe(recipe, "smoke", {"train.max_steps": 2, **overrides}),
        FitOptions(out=tmp_path / name, progress=False, experiment="tests-init", init=init),
    )
    assert result.status == "FINISHED", result.message
    return result


def test_init_starts_a_new_run_from_the_weights_of_another(tmp_path):
    from mlflow import MlflowClient

    real = des18_strips(tmp_path / "real", count=4, size=64)
    parent = _smoke_fit(tmp_path, "parent", **{"optim.lr": 1e-2})
    start = load_checkpoint(parent.checkpoint)
    # With a vanishing rate the child ends where it started: at the parent's weights.
    child = _smoke_fit(
        tmp_path,
        "child",
        "ours-finetune",
        init=parent.run_id,
        **{"data.path": str(real), "optim.lr": 1e-12, "train.epochs": 2},
    )
    end = load_checkpoint(child.checkpoint)
    assert (
        child.run_id != parent.run_id and end["step"] == 2 and end["init"]["svbrdf.init_run"] == parent.run_id
    )
    for name, tensor in start["generator"].items():
        assert torch.allclose(end["generator"][name], tensor, atol=1e-8), name
    tags = MlflowClient().get_run(child.run_id).data.tags
    assert tags["svbrdf.init"] == f"run {parent.run_id}" and tags["svbrdf.init_run"] == parent.run_id
    assert tags["svbrdf.init_step"] == "2" and tags["svbrdf.init_discriminator"] == "taken"
    # and a fresh fit of the same recipe does not start there
    fresh = load_checkpoint(
        _smoke_fit(tmp_path, "fresh", "ours-finetune", **{"data.path": str(real)}).checkpoint
    )
    assert any(not torch.allclose(fresh["generator"][k], t, atol=1e-3) for k, t in start["generator"].items())


def test_init_from_a_folder_takes_the_generator_when_the_discriminator_differs(tmp_path):
    parent = _smoke_fit(tmp_path, "parent", "no-adv")
    child = _smoke_fit(tmp_path, "child", init=str(tmp_path / "parent"))
    assert load_checkpoint(child.checkpoint)["init"]["svbrdf.init_discriminator"] == "new"
    assert parent.checkpoint is not None


def test_init_refuses_another_generator_and_other_mistakes(tmp_path):
    _smoke_fit(tmp_path, "parent")
    parent = str(tmp_path / "parent" / "last.pt")
    _assert_refused(
        _cli(tmp_path, "--recipe", "ours", "--size", "cpu", "--init", parent),
        f"--init {parent}: its generator does not match recipe 'ours'",
        "base_channels",
    )
    _assert_refused(
        _cli(tmp_path, "--recipe", "radn", "--size", "smoke", "--init", parent), "generator does not match"
    )
    _assert_refused(
        _cli(tmp_path, "--recipe", "ours", "--size", "smoke", "--init", "nowhere"), "--init nowhere"
    )
    _assert_refused(
        _cli(tmp_path, "--recipe", "ours", "--size", "smoke", "--init", "0" * 32), f"MLflow run {'0' * 32}"
    )
    _assert_refused(_cli(tmp_path, "--resume", "--init", parent), "--init starts a new fit")


def test_procedural_materials_are_a_plain_source_of_a_mix():
    # a mix of one source is that source in another order
    proc = ProceduralMaterials(6, 16, seed=3)
    mix = Mixture([proc], [2.0], count=6, seed=0)
    names = sorted(mix[k]["name"] for k in range(6))
    assert names == sorted(proc[k]["name"] for k in range(6))


def test_each_entry_photographs_its_samples_under_its_own_capture():
    mix = [{"source": "procedural", "weight": 1}, {"source": "procedural", "weight": 1, "capture": "handheld"}]
    recipe = load_recipe("ours-mix", "smoke", {"data.mix": mix, "data.count": 8, "data.capture": "phone"})
    train, val = build_datasets(recipe)
    first, second = train.sources
    assert first.photo == PhotoSettings.preset("phone")  # the section's capture where the entry names none
    assert second.photo == PhotoSettings.preset("handheld")
    same = ProceduralMaterials(8, first.resolution, seed=recipe.data.seed, photo=PhotoSettings.preset("handheld"))
    assert torch.equal(second[3]["input"], same[3]["input"])
    assert not torch.equal(first[3]["input"], second[3]["input"])  # one material, two photos
    assert {type(v.photo) for v in val.datasets} == {PhotoSettings} and val.datasets[1].photo == second.photo


def test_the_general_recipe_trains_the_resize_generator_on_phone_photos(tmp_path):
    recipe = load_recipe("ours-general", "smoke", {"data.count": 16})
    train, val = build_datasets(recipe)
    assert isinstance(train, ProceduralMaterials) and train.photo == PhotoSettings.preset("phone")
    assert val.photo == PhotoSettings.preset("phone")
    result = _smoke_fit(tmp_path, "general", "ours-general")
    config = load_checkpoint(result.checkpoint)["recipe"]["generator"]["config"]
    assert (config["upsample"], config["input_norm"], config["input_level"]) == ("resize", "median", True)
