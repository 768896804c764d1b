"""Learning-rate schedules in samples seen: the same on any data set size, resumable as a
function of the step, and a warning when a schedule would stop the learning early."""

from __future__ import annotations

import pytest

from svbrdf_train.recipe import OptimSection, load_recipe, recipe_from_dict
from svbrdf_train.training.schedule import WARN_BELOW, LrSchedule
from svbrdf_train.training.trainer import FitOptions, fit


def _schedule(per_step=8, samples_per_epoch=16, **optim):
    return LrSchedule(OptimSection(**optim), per_step, samples_per_epoch)


def test_the_sample_period_does_not_depend_on_the_data_set_size():
    small = _schedule(per_step=4, samples_per_epoch=16, decay_every_samples=400)
    large = _schedule(per_step=4, samples_per_epoch=200_000, decay_every_samples=400)
    for step in (0, 99, 100, 101, 250, 1000):
        assert small.factor(step) == large.factor(step)
    assert small.factor(99) == 1.0 and small.factor(100) == 0.5  # 400 samples seen at step 100
    assert small.factor(200) == 0.25


def test_the_epoch_period_is_still_there_and_counts_epochs():
    s = _schedule(per_step=4, samples_per_epoch=16, decay_every_samples=None, decay_every_epochs=2)
    assert s.period == 32
    assert [s.factor(k) for k in (0, 7, 8, 16)] == [1.0, 1.0, 0.5, 0.25]


def test_no_decay_and_warm_up():
    flat = _schedule(decay_every_samples=None)
    assert flat.period is None and flat.factor(10**6) == 1.0
    assert _schedule(decay=1.0).period is None
    warm = _schedule(per_step=8, warmup_samples=80, decay_every_samples=None)
    factors = [warm.factor(k) for k in range(12)]
    assert factors[0] == pytest.approx(0.1) and factors[9] == 1.0 and factors[11] == 1.0
    assert all(a < b for a, b in zip(factors[:9], factors[1:10], strict=True))


@pytest.mark.parametrize("decay", [0.5, 0.1, 0.9])
def test_first_step_below_is_the_first_one(decay):
    s = _schedule(per_step=4, decay=decay, decay_every_samples=12)
    step = s.first_step_below(WARN_BELOW)
    assert s.factor(step) < WARN_BELOW <= s.factor(step - 1)


def test_the_warning_names_the_setting_that_kills_the_rate():
    # the case: 17 strips at batch 4, halved every epoch of 4 steps
    s = _schedule(per_step=4, samples_per_epoch=16, decay_every_samples=None, decay_every_epochs=1)
    text = s.warning(1000, "the step budget")
    assert text is not None
    assert "optim.decay_every_epochs=1" in text and "step 28" in text and "decay_every_samples" in text
    assert s.warning(200, "x") is None  # step 28 is past the first tenth of 200 steps
    paper = _schedule(per_step=8, samples_per_epoch=200_000)  # 400k samples: 7 halvings = 350k steps
    assert paper.warning(500_000, "x") is None


def test_settings_that_cannot_work_are_refused():
    with pytest.raises(ValueError, match="both set"):
        OptimSection(decay_every_samples=10, decay_every_epochs=1)
    with pytest.raises(ValueError, match="decay_every_samples must be at least 1"):
        OptimSection(decay_every_samples=0)
    with pytest.raises(ValueError, match="warmup_samples"):
        OptimSection(warmup_samples=-1)


def test_a_checkpoint_recipe_from_before_sample_schedules_keeps_its_epoch_period():
    old = load_recipe("ours", "smoke").to_dict()
    del old["optim"]["decay_every_samples"]
    old["optim"]["decay_every_epochs"] = 2
    recipe = recipe_from_dict(old)
    assert recipe.optim.decay_every_epochs == 2 and recipe.optim.decay_every_samples is None


def _loss_thirds(tmp_path, name, **overrides):
    """Mean training loss over the first, second and last third of a 60-step fit on 4 materials."""
    from mlflow import MlflowClient

    settings = {
        "data.count": 4,
        "train.epochs": 1000,
        "train.max_steps": 60,
        "train.validate_every": 60,
        "train.checkpoint_every": 60,
        "optim.lr": 2e-3,
        **overrides,
    }
    result = fit(
        load_recipe("no-adv", "smoke", settings),
        FitOptions(out=tmp_path / name, progress=False, experiment="tests-schedule"),
    )
    assert result.status == "FINISHED", result.message
    history = sorted(MlflowClient().get_metric_history(result.run_id, "train/loss"), key=lambda m: m.step)
    values = [m.value for m in history]
    assert len(values) == 60
    return [sum(values[k : k + 20]) / 20 for k in (0, 20, 40)], MlflowClient().get_run(result.run_id)


def test_a_fit_on_a_few_samples_keeps_learning_across_its_budget(tmp_path):
    """4 materials, 2 steps an epoch: the default schedule (in samples) keeps the loss falling to
    the end; a period in epochs (a tenth every epoch) freezes it within a few steps, and the fit
    says so in its run."""
    (first, middle, last), run = _loss_thirds(tmp_path, "samples")
    assert middle < first and last < 0.97 * middle, (first, middle, last)
    assert "svbrdf.warning" not in run.data.tags

    (first, middle, last), run = _loss_thirds(
        tmp_path,
        "epochs",
        **{"optim.decay_every_samples": None, "optim.decay_every_epochs": 1, "optim.decay": 0.1},
    )
    # Frozen: the last two thirds differ by the batches' own noise only (about 1%, which
    # depends on the materials drawn), against a fall of more than 3% while learning.
    assert abs(last - middle) < 0.02 * middle, (first, middle, last)
    warning = run.data.tags["svbrdf.warning"]
    assert "optim.decay_every_epochs=1" in warning and "of the budget of 60 steps" in warning


@pytest.mark.parametrize(("rule", "factor"), [("none", 1.0), ("sqrt", 2.0), ("linear", 4.0)])
def test_the_rates_follow_a_larger_batch_by_the_recipes_rule(rule, factor):
    """optim.batch_rule: a batch 4x the reference scales lr and d_lr by 1, 2 or 4 (issue 37)."""
    from svbrdf_train.training import distributed
    from svbrdf_train.training.step import GanStep

    recipe = load_recipe("ours", "smoke", {"train.batch": 8, "optim.batch_rule": rule, "optim.batch_reference": 2})
    gan = GanStep(recipe, distributed.Dist(), 8)
    assert gan.g_opt.param_groups[0]["lr"] == pytest.approx(recipe.optim.lr * factor)
    assert gan.d_opt.param_groups[0]["lr"] == pytest.approx(recipe.optim.d_lr * factor)
