"""The training step as one object (GanStep), the ways it can run, and the checkpoint cadence."""

from __future__ import annotations

import io

import pytest
import torch

from svbrdf_train.data.fitdata import build_datasets
from svbrdf_train.recipe import load_recipe
from svbrdf_train.training import distributed
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.order import BatchOrder
from svbrdf_train.training.step import GanStep
from svbrdf_train.training.trainer import FitOptions, fit


def _gan(recipe):
    train, _ = build_datasets(recipe)
    order = BatchOrder(train, recipe, 0, 1, torch.device("cpu"))
    return GanStep(recipe, distributed.Dist(), order.epoch_samples), order


def _recipe(name="ours", **overrides):
    base = {"data.count": 8, "train.epochs": 3, "train.max_steps": None, "optim.g_steps_per_d": 2}
    return load_recipe(name, "smoke", {**base, **overrides})


def test_a_step_continued_from_its_state_dict_is_the_same_step():
    """Two steps, the state saved; a new GanStep loaded from it takes the third step exactly as
    the first would have: same loss terms, same weights, same Adam moments."""
    recipe = _recipe()
    a, order = _gan(recipe)
    batches = list(order.batches(0))[:3]
    torch.manual_seed(5)
    for batch in batches[:2]:
        assert a(batch)[1] is None
    saved = io.BytesIO()  # through bytes, as a checkpoint goes: no tensor shared with `a`
    torch.save((a.state_dict(), a.rng_state()), saved)
    saved.seek(0)
    state, rng = torch.load(saved, weights_only=True)
    b, _ = _gan(recipe)
    assert not torch.equal(next(iter(b.generator.parameters())), next(iter(a.generator.parameters())))
    b.load_state_dict(state)
    b.set_rng_state(rng)
    terms_b, bad_b = b(batches[2])
    a.set_rng_state(rng)  # the global random state is shared by both objects in this process
    terms_a, bad_a = a(batches[2])
    assert bad_a is None and bad_b is None and a.step == b.step == 3
    assert terms_a == terms_b
    for (name, pa), pb in zip(a.generator.state_dict().items(), b.generator.state_dict().values(), strict=True):
        assert torch.equal(pa, pb), name
    sa, sb = a.state_dict()["optimizers"]["g"]["state"], b.state_dict()["optimizers"]["g"]["state"]
    assert all(torch.equal(sa[k]["exp_avg_sq"], sb[k]["exp_avg_sq"]) for k in sa)


def test_the_discriminator_steps_every_g_steps_per_d():
    recipe = _recipe(**{"optim.g_steps_per_d": 2})
    gan, order = _gan(recipe)
    seen = [("d_loss" in gan(batch)[0]) for batch in list(order.batches(0))[:4]]
    assert seen == [True, False, True, False]


@pytest.mark.parametrize(
    "settings",
    [{"train.channels_last": True}, {"train.precision": "bf16"}],
    ids=["channels-last", "bf16"],
)
def test_each_way_of_running_the_step_learns_with_finite_values(settings):
    """channels-last and bf16 autocast take finite steps forward and backward, the maps stay
    float32, and the generator's weights move."""
    recipe = _recipe(**settings)
    gan, order = _gan(recipe)
    gan.prepare()
    before = [p.detach().clone() for p in gan.generator.parameters()]
    for batch in list(order.batches(0))[:2]:
        terms, bad = gan(batch)
        assert bad is None
        assert all(torch.isfinite(torch.tensor(v)) for v in terms.values())
    moved = [not torch.equal(p, q) for p, q in zip(gan.generator.parameters(), before, strict=True)]
    assert sum(moved) > len(moved) // 2
    assert all(p.dtype == torch.float32 for p in gan.generator.parameters())


@pytest.mark.slow
def test_a_compiled_step_learns_and_its_generator_predicts_as_the_eager_one():
    """torch.compile of both networks: the steps are finite and move the weights, and the compiled
    generator's maps (eval mode: no dropout, whose random stream compiled code draws differently)
    equal the eager network's to float32 rounding."""
    recipe = _recipe("radn", **{"train.compile": True})
    gan, order = _gan(recipe)
    gan.prepare()
    before = [p.detach().clone() for p in gan.generator.parameters()]
    batches = list(order.batches(0))[:2]
    for batch in batches:
        terms, bad = gan(batch)
        assert bad is None and all(torch.isfinite(torch.tensor(v)) for v in terms.values())
    assert any(not torch.equal(p, q) for p, q in zip(gan.generator.parameters(), before, strict=True))
    gan.G.eval()
    with torch.no_grad():
        compiled = gan.G(batches[0]["input"]).pack()
        eager = gan.generator(batches[0]["input"]).pack()
    torch.testing.assert_close(compiled, eager, rtol=1e-4, atol=1e-5)


def _fit_recording_saves(tmp_path, monkeypatch, **settings):
    import svbrdf_train.training.hooks as hooks

    saved = []
    real = hooks.save_checkpoint

    def record(path, state):
        saved.append((path.name, state["step"], "optimizers" in state))
        return real(path, state)

    monkeypatch.setattr(hooks, "save_checkpoint", record)
    recipe = _recipe("radn", **{"train.max_steps": 4, **settings})
    result = fit(recipe, FitOptions(out=tmp_path / "out", progress=False, track=False))
    assert result.status == "FINISHED" and result.step == 4
    return saved


def test_checkpoints_follow_steps_or_time_and_the_end(tmp_path, monkeypatch):
    """By steps only: every checkpoint_every steps and at the end. By time: whenever
    checkpoint_minutes have passed (a tiny interval: after every step; none: only at the end).
    The weights file (no optimiser state) is written at the end."""
    by_steps = _fit_recording_saves(
        tmp_path / "a", monkeypatch, **{"train.checkpoint_every": 3, "train.checkpoint_minutes": None}
    )
    assert [s for name, s, _ in by_steps if name == "last.pt"] == [3, 4]
    by_time = _fit_recording_saves(
        tmp_path / "b", monkeypatch, **{"train.checkpoint_every": None, "train.checkpoint_minutes": 1e-9}
    )
    assert [s for name, s, _ in by_time if name == "last.pt"] == [1, 2, 3, 4]
    at_end = _fit_recording_saves(
        tmp_path / "c", monkeypatch, **{"train.checkpoint_every": None, "train.checkpoint_minutes": None}
    )
    assert [(n, s) for n, s, _ in at_end] == [("last.pt", 4), ("weights.pt", 4)]
    assert [full for _, _, full in at_end] == [True, False]


def test_weights_are_uploaded_on_their_own_slower_cadence(tmp_path, monkeypatch):
    """upload_minutes tiny: the weights go with every checkpoint; large: only at the end."""
    often = _fit_recording_saves(
        tmp_path / "a", monkeypatch, **{"train.checkpoint_every": 1, "train.upload_minutes": 1e-9}
    )
    assert [s for n, s, _ in often if n == "weights.pt"] == [1, 2, 3, 4]
    rarely = _fit_recording_saves(
        tmp_path / "b", monkeypatch, **{"train.checkpoint_every": 1, "train.upload_minutes": 60}
    )
    assert [s for n, s, _ in rarely if n == "weights.pt"] == [4]


def test_the_weights_file_is_the_checkpoint_without_what_resuming_needs(tmp_path):
    """weights.pt holds the recipe, step and both networks' weights, equal to the checkpoint's,
    and none of the optimiser, schedule or random state: a third of the bytes or less."""
    recipe = _recipe("ours", **{"train.max_steps": 2})
    fit(recipe, FitOptions(out=tmp_path, progress=False, track=False))
    full = load_checkpoint(tmp_path / "last.pt")
    weights = load_checkpoint(tmp_path / "weights.pt")
    assert not {"optimizers", "rng", "schedule"} & set(weights)
    assert weights["recipe"] == full["recipe"] and weights["step"] == full["step"] == 2
    for net in ("generator", "discriminator"):
        assert weights[net].keys() == full[net].keys()
        assert all(torch.equal(weights[net][k], full[net][k]) for k in full[net])
    assert (tmp_path / "weights.pt").stat().st_size * 2.5 < (tmp_path / "last.pt").stat().st_size


def test_a_fit_with_batches_made_in_the_training_process_is_the_same_fit(tmp_path):
    """data.generate: device on the CPU makes the very batches the DataLoader makes, so the fit
    reaches the same weights bit for bit (on a GPU the values differ by rounding and photo noise)."""
    weights = {}
    for generate in ("workers", "device"):
        recipe = _recipe("radn", **{"train.max_steps": 3, "data.generate": generate})
        fit(recipe, FitOptions(out=tmp_path / generate, progress=False, track=False))
        weights[generate] = load_checkpoint(tmp_path / generate / "last.pt")["generator"]
    assert weights["workers"].keys() == weights["device"].keys()
    assert all(torch.equal(weights["workers"][k], weights["device"][k]) for k in weights["workers"])
