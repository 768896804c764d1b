"""Bad values are refused before any work: one line naming the field or flag and the value, exit 2.

Each row is a command line of ``svbrdf-train`` run in-process; recipe values go through
``svbrdf-train recipes`` (what ``fit`` loads the same way, without training). Refusals of the
recipe layer print ``svbrdf-train: error: ...`` alone; click's own usage errors print a usage
block and one ``Error: ...`` line, which is fine as long as it is one line naming the option.
"""

from __future__ import annotations

import pytest

from svbrdf_train.cli import main

# A recipe file whose base values are broken where a size overrides them, so that loading
# it at the overriding size alone never saw them.
MASKED_BASE = "base: ours\ntrain: {batch: 0}\nsizes:\n  smoke: {train.batch: 2}\n  cpu: {train.batch: 2}\n"
MASKED_SIZE = "base: ours\nsizes:\n  cpu: {optim.lr: -1}\n"
BAD_ATTENTION = "base: ours\ngenerator: {name: ours, config: {attention: multiscle}}\n"
BAD_SCALES = "base: ours\ngenerator: {name: ours, config: {attention: cbam, attention_config: {scales: [1, 2]}}}\n"

SMOKE = ["recipes", "ours", "--size", "smoke"]


def _set(*items: str) -> list[str]:
    return [*SMOKE, *(a for item in items for a in ("--set", item))]


RECIPE_ROWS = [
    # the cases: a resolution the generator cannot take, an attention typo in a file,
    # a bad value hidden by a size override
    (_set("train.resolution=30"), ["train.resolution is 30", "multiples of 16 (2**depth, depth 4)", "16 and 32", "size smoke"]),
    (_set("generator.config.preset=paper"), ["train.resolution is 32", "multiples of 256", "generator.config.preset=paper"]),
    (_set("train.resolution=16", "discriminator.config.preset=paper"), ["discriminator 'patchgan'", "at least 24", "got 16x16"]),
    (["recipes", "FILE:BAD_ATTENTION", "--size", "smoke"], ["field 'attention'", "'multiscle'", "'multiscale'"]),
    (["recipes", "FILE:BAD_SCALES"], ["field 'attention_config'", "'cbam'", "'scales'"]),
    (["recipes", "FILE:MASKED_BASE", "--size", "smoke"], ["(size paper)", "batch must be at least 1, got 0"]),
    (["recipes", "FILE:MASKED_SIZE", "--size", "smoke"], ["(size cpu)", "lr must be a finite number > 0, got -1"]),
    # ranges of every section
    (_set("optim.lr=0"), ["'optim'", "lr must be a finite number > 0, got 0", "optim.lr=0"]),
    (_set("optim.lr=.nan"), ["lr must be a finite number > 0, got nan"]),
    (_set("optim.d_lr=-1e-4"), ["d_lr must be a finite number > 0, got -0.0001"]),
    (_set("optim.betas=[0.5, 1.0]"), ["betas[1] must be in [0, 1)", "got 1.0"]),
    (_set("optim.decay=0"), ["decay must be in (0, 1]", "got 0"]),
    (_set("optim.g_steps_per_d=0"), ["g_steps_per_d must be at least 1, got 0"]),
    (_set("optim.warmup_samples=-8"), ["warmup_samples must be at least 0, got -8"]),
    (_set("loss.adv=-0.1"), ["adv must be a finite number >= 0, got -0.1"]),
    (_set("loss.render=.inf"), ["render must be a finite number >= 0, got inf"]),
    (_set("loss.eps=0"), ["eps must be a finite number > 0, got 0"]),
    (_set("loss.maps.normal=-1"), ["maps.normal must be a finite number >= 0, got -1"]),
    (_set("loss.maps={normal: 0, diffuse: 0, roughness: 0, specular: 0}"), ["every weight of maps is 0"]),
    (_set("train.batch=0"), ["batch must be at least 1, got 0"]),
    (_set("train.epochs=-1"), ["epochs must be at least 1, got -1"]),
    (_set("train.resolution=4"), ["resolution must be in [8, 8192]", "got 4"]),
    (_set("train.resolution=100000"), ["resolution must be in [8, 8192]", "got 100000"]),
    (_set("train.max_steps=0"), ["max_steps must be at least 1 (or null: no limit), got 0"]),
    (_set("train.max_minutes=-1"), ["max_minutes must be a finite number >= 0, got -1"]),
    (_set("train.log_every=0"), ["log_every must be at least 1, got 0"]),
    (_set("train.seed=4294967296"), ["seed must be in [0, 4294967295]", "got 4294967296"]),
    (_set("train.renderings=6"), ["discriminator.config.renderings is 9 but train.renderings is 6"]),
    (_set("data.count=0"), ["count must be at least 1, got 0"]),
    (_set("data.count=1"), ["data.count is 1", "train.batch 2"]),
    (_set("data.seed=-1"), ["seed must be in [0, 4294967295]", "got -1"]),
    (_set("data.workers=-1"), ["workers must be at least 0, got -1"]),
    (_set("data.generate=gpu"), ["field 'generate' must be one of 'workers', 'device'", "got 'gpu'"]),
    (_set("data.path=train.h5"), ["data.path is train.h5 but data.source is 'procedural'", "data.path=null"]),
    (_set("data.source=mix", "data.mix=[{source: procedural, weight: 0}]"), ["mix[0].weight", "got 0"]),
    (_set("generator.config.attention=nope"), ["field 'attention'", "unknown attention module 'nope'"]),
    (_set("generator.config.attention_config.scales=[0]"), ["field 'attention_config'", "scales must be", "(0,)"]),
    (_set("generator.config.init_std=-1"), ["init_std must be a finite number >= 0", "got -1"]),
    (_set("generator.config.dropout=1.5"), ["dropout must be in [0, 1)", "got 1.5"]),
    (_set("discriminator.config.layers=0"), ["base_channels and layers must be positive", "0"]),
]

FLAG_ROWS = [
    (["fit", "--recipe", "ours", "--size", "smoke", "--max-minutes", "-1"], ["'--max-minutes'", "-1"]),
    (["fit", "--recipe", "ours", "--size", "smoke", "--max-minutes", "nan"], ["'--max-minutes'", "'nan' is not a finite number"]),
    (["fit", "--recipe", "ours", "--size", "smoke", "--max-minutes", "inf"], ["'--max-minutes'", "'inf' is not a finite number"]),
    (["fit", "--recipe", "ours", "--size", "smoke", "--max-steps", "0"], ["'--max-steps'", "0 is not in the range x>=1"]),
    (["fit", "--recipe", "ours", "--size", "smoke", "--max-steps", "-5"], ["'--max-steps'", "-5"]),
    (["fit", "--recipe", "ours", "--size", "smoke", "--device", "cuda:x"], ["--device 'cuda:x'", "cpu, cuda or cuda:K"]),
    (["fit", "--resume", "--size", "cpu"], ["--size cpu goes with --recipe"]),
    (["recipes", "--set", "train.batch=4"], ["--set train.batch=4", "give its NAME or FILE"]),
    (["recipes", "--size", "cpu"], ["--size cpu", "give its NAME or FILE"]),
    (["data", "make", "--count", "0", "-o", "x.h5"], ["'--count'", "0 is not in the range x>=1"]),
    (["data", "make", "--count", "-5", "-o", "x.h5"], ["'--count'", "-5"]),
    (["data", "make", "-n", "4", "--resolution", "7", "-o", "x.h5"], ["'--resolution'", "7 is not in the range 8<=x<=4096"]),
    (["data", "make", "-n", "4", "--resolution", "100000", "-o", "x.h5"], ["'--resolution'", "100000"]),
    (["data", "make", "-n", "4", "--batch", "0", "-o", "x.h5"], ["'--batch'", "0 is not in the range 1<=x<=1024"]),
    (["data", "make", "-n", "4", "--mix", "nan", "-o", "x.h5"], ["'--mix'", "'nan' is not a finite number"]),
    (["data", "make", "-n", "4", "--seed", "-1", "-o", "x.h5"], ["'--seed'", "-1 is not in the range 0<=x<=4294967295"]),
    (["data", "import", ".", "--crop", "4", "-o", "x.h5"], ["'--crop'", "4 is not in the range 8<=x<=4096"]),
    (["data", "import", ".", "--full", "--crop", "128", "-o", "x.h5"], ["--crop 128 and --full"]),
    (["data", "compare", ".", "--rows", "4"], ["--rows 4", "give -o"]),
    (["data", "sheet", "--mix", "inf", "-o", "s.png"], ["'--mix'", "inf"]),
    (["data", "sheet", "--seed", "99999999999", "-o", "s.png"], ["'--seed'", "99999999999"]),
    (["predict", "p.jpg", "--checkpoint", "c.pt", "-o", "o", "--tiles", "--map-size", "100000"], ["argument --map-size", "expected an integer from 1 to 8192, got 100000"]),
    (["predict", "p.jpg", "--checkpoint", "c.pt", "-o", "o", "--tiles", "--map-size", "0"], ["argument --map-size", "expected an integer from 1 to 8192, got 0"]),
    (["predict", "p.jpg", "--checkpoint", "c.pt", "-o", "o", "--device", "gpu"], ["--device 'gpu'", "cpu, cuda or cuda:K"]),
]

FILES = {"BAD_ATTENTION": BAD_ATTENTION, "BAD_SCALES": BAD_SCALES, "MASKED_BASE": MASKED_BASE, "MASKED_SIZE": MASKED_SIZE}


def _refused(capsys, argv, fragments, tmp_path):
    argv = list(argv)
    for i, arg in enumerate(argv):
        if arg.startswith("FILE:"):
            key = arg[5:]
            (tmp_path / f"{key.lower()}.yaml").write_text(FILES[key])
            argv[i] = str(tmp_path / f"{key.lower()}.yaml")
            fragments = [*fragments, f"{key.lower()}.yaml"]
    code = main(argv)
    captured = capsys.readouterr()
    err = captured.err
    assert code == 2, (argv, code, err)
    assert "Traceback" not in err and "Traceback" not in captured.out
    errors = [line for line in err.splitlines() if "error:" in line.lower()]
    assert len(errors) == 1, err
    if err.startswith("svbrdf-train: error: "):
        assert err.count("\n") == 1, err  # our own refusals: that line and nothing else
    for fragment in fragments:
        assert fragment in errors[0], (fragment, errors[0])
    assert captured.out == ""  # nothing was printed as done
    assert not any(tmp_path.glob("x.h5")) and not (tmp_path / "s.png").exists() and not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, fragments", RECIPE_ROWS)
def test_bad_recipe_values_are_refused_when_the_recipe_loads(argv, fragments, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(capsys, argv, fragments, tmp_path)


@pytest.mark.parametrize("argv, fragments", FLAG_ROWS)
def test_bad_flags_are_refused_before_any_work(argv, fragments, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(capsys, argv, fragments, tmp_path)


def test_fit_refuses_a_recipe_value_before_training(tmp_path, capsys, monkeypatch):
    # train.resolution=30 passed `recipes` and failed in the first forward pass with 50 lines.
    monkeypatch.chdir(tmp_path)
    argv = ["fit", "-q", "--no-track", "--recipe", "ours", "--size", "smoke", "--out", "run", "--set", "train.resolution=30"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("svbrdf-train: error: ") and err.count("\n") == 1 and "train.resolution is 30" in err
    assert not (tmp_path / "run").exists()


def test_good_values_still_load_and_a_file_reads_numbers_like_set(tmp_path, capsys, monkeypatch):
    import yaml

    recipes = tmp_path / "recipes"
    recipes.mkdir()
    (recipes / "base.yaml").write_text("base: ours\noptim: {lr: 3e-4}\n")
    (recipes / "mine.yaml").write_text("base: base.yaml\ntrain: {max_minutes: 1e1}\n")
    monkeypatch.chdir(tmp_path)  # not the recipes' folder: base.yaml is found beside mine.yaml
    assert main(["recipes", str(recipes / "mine.yaml"), "--size", "smoke", "--set", "optim.d_lr=5e-5"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["optim"]["lr"] == 3e-4 and printed["optim"]["d_lr"] == 5e-5
    assert printed["train"]["max_minutes"] == 10.0 and printed["train"]["resolution"] == 32


def test_a_gpu_index_the_machine_lacks_is_named_as_such(monkeypatch):
    # cuda:K beyond the GPUs there failed later in torch; cuda:x was a traceback.
    import torch

    from svbrdf_train.errors import TrainingError
    from svbrdf_train.training.distributed import pick_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert pick_device("cuda:1") == torch.device("cuda:1")
    assert pick_device("cuda", local_rank=3) == torch.device("cuda:1")
    with pytest.raises(TrainingError, match=r"--device cuda:2: this machine has 2 GPU\(s\), cuda:0 to cuda:1"):
        pick_device("cuda:2")
    with pytest.raises(TrainingError, match="--device 'cuda:x': expected auto, cpu, cuda or cuda:K"):
        pick_device("cuda:x")


# -- checkpoint headers (issue 27): every field checked before use, one line naming it ------------


def _resumable() -> dict:
    """The header of a checkpoint that ``--resume`` can use (weights, Adam and random states)."""
    import torch

    adam = {"state": {}, "param_groups": [{"params": [0], "lr": 2e-5}]}
    return {
        "format": 1, "recipe": {"train": {"epochs": 1}}, "step": 3, "epoch": 0,
        "generator": {"w": torch.zeros(2)}, "discriminator": None,
        "optimizers": {"g": adam}, "rng": [{"torch": torch.get_rng_state()}],
        "train_seconds": 1.5, "wall_seconds": 2.0, "world_size": 1, "run_id": None, "init": None,
    }  # fmt: skip


HEADER_ROWS = [
    ({"recipe": [1, 2]}, "field 'recipe' must be a mapping of recipe sections, got list"),
    ({"recipe": None}, "no 'recipe' in the checkpoint"),
    ({"step": "ten"}, "field 'step' must be a whole number of steps >= 0, got 'ten'"),
    ({"step": -5}, "field 'step' must be a whole number of steps >= 0, got -5"),
    ({"step": True}, "field 'step'"),
    ({"train_seconds": float("nan")}, "field 'train_seconds' must be a finite number of seconds >= 0, got nan"),
    ({"wall_seconds": -1.0}, "field 'wall_seconds'"),
    ({"world_size": 0}, "field 'world_size'"),
    ({"generator": [1]}, "field 'generator' must be a mapping of weight names to tensors, got list"),
    ({"optimizers": {}}, "field 'optimizers' must be the Adam states of 'g' (state and param_groups)"),
    ({"optimizers": {"g": {"state": {}, "param_groups": []}}}, "field 'optimizers'"),
    ({"rng": "garbage"}, "field 'rng' must be a list of 1 random state(s), one per process, got 'garbage'"),
    ({"rng": [{"torch": "x"}]}, "field 'rng[0].torch' must be torch's CPU random state"),
    ({"rng": [{"scene": 1}]}, "field 'rng[0].torch'"),
]


@pytest.mark.parametrize("change, says", HEADER_ROWS, ids=[f"{next(iter(c))}-{i}" for i, (c, _) in enumerate(HEADER_ROWS)])
def test_a_damaged_checkpoint_header_is_refused_naming_the_file_and_the_field(tmp_path, change, says):
    import torch

    from svbrdf_train.errors import CheckpointError
    from svbrdf_train.training.checkpoint import check_resumable, load_checkpoint

    good = tmp_path / "good.pt"
    torch.save(_resumable(), good)
    check_resumable(load_checkpoint(good), str(good))  # the undamaged header passes
    state = {**_resumable(), **change}
    state = {k: v for k, v in state.items() if not (k in change and v is None)}
    path = tmp_path / "last.pt"
    torch.save(state, path)
    with pytest.raises(CheckpointError) as e:
        check_resumable(load_checkpoint(path, mmap=True), str(path))
    message = str(e.value)
    assert message.startswith(f"{path}: ") and says in message and "\n" not in message
