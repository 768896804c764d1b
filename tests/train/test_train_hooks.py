"""The hooks a fit runs between its steps, and the one runner that applies their cadences.

A fit that ends early (its time budget, a stop request) still logs its last window of
``train/`` metrics: the hooks run after the last step whatever ended the fit. A hook sees a
narrow, read-only view of the run and returns what it changes, which the runner applies.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from svbrdf_train.recipe import load_recipe
from svbrdf_train.training import step
from svbrdf_train.training.clock import Stopwatch, TrainClock
from svbrdf_train.training.distributed import Dist
from svbrdf_train.training.hooks import Cadence, HookRunner
from svbrdf_train.training.run import Run, RunChange, StepEnd
from svbrdf_train.training.trainer import FitOptions, fit


@pytest.fixture
def store(tmp_path, monkeypatch):
    """A SQLite MLflow store of the test's own, and its client."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return MlflowClient(uri)


def _losses_of_each_step(monkeypatch, *, stop_at: int | None = None) -> list[float]:
    """The generator loss of every step the fit makes, in order; with ``stop_at``, a SIGTERM (a
    stop request) is sent to this process during that step."""
    losses: list[float] = []
    real = step.GanStep.__call__

    def recording(self, batch):
        terms, bad = real(self, batch)
        losses.append(terms["loss"])
        if stop_at is not None and self.step == stop_at:
            os.kill(os.getpid(), signal.SIGTERM)
        return terms, bad

    monkeypatch.setattr(step.GanStep, "__call__", recording)
    return losses


def _history(client, run_id: str, key: str) -> list[tuple[int, float]]:
    return sorted((m.step, m.value) for m in client.get_metric_history(run_id, key))


def test_a_fit_stopped_by_its_time_budget_logs_its_last_train_window(tmp_path, store, monkeypatch):
    """A zero-minute budget ends the fit after its first step, long before train.log_every: the
    step's loss terms, rate and time are still logged at that step."""
    losses = _losses_of_each_step(monkeypatch)
    recipe = load_recipe("ours", "smoke", {
        "train.max_steps": None, "train.epochs": 1000, "train.max_minutes": 0.0, "train.log_every": 10,
    })  # fmt: skip
    result = fit(recipe, FitOptions(out=tmp_path / "fit", progress=False, experiment="tests-hooks"))
    assert result.status == "FINISHED" and result.step == 1 and "time budget" in result.message
    loss = _history(store, result.run_id, "train/loss")
    assert [s for s, _ in loss] == [1]
    assert loss[0][1] == pytest.approx(losses[0], rel=1e-6)
    for key in ("train/lr", "train/samples_per_s", "train/epoch", "train/seconds"):
        ((s, value),) = _history(store, result.run_id, key)
        assert s == 1 and math.isfinite(value) and value > 0, key


def test_a_fit_stopped_by_a_request_logs_the_mean_of_its_last_window(tmp_path, store, monkeypatch):
    """A stop request (SIGTERM) during step 2 of a fit logging every 3 steps: the fit stops after
    step 2 (KILLED) and logs the mean of steps 1 and 2 at step 2."""
    losses = _losses_of_each_step(monkeypatch, stop_at=2)
    recipe = load_recipe("ours", "smoke", {"train.max_steps": 6, "train.epochs": 10, "train.log_every": 3})
    result = fit(recipe, FitOptions(out=tmp_path / "fit", progress=False, experiment="tests-hooks"))
    assert result.status == "KILLED" and result.step == 2, result.message
    assert len(losses) == 2
    loss = _history(store, result.run_id, "train/loss")
    assert [s for s, _ in loss] == [2]
    assert loss[0][1] == pytest.approx(sum(losses) / 2, rel=1e-6)


# -- the runner, on its own ------------------------------------------------------------------------


def _run(tmp_path=Path("unused"), *, main: bool = True) -> Run:
    """A real run around stand-ins for what a fit builds (no networks, no data): what the runner
    and the view read of it."""
    gan = SimpleNamespace(
        step=0,
        g_opt=SimpleNamespace(param_groups=[{"lr": 2e-5}]),
        schedule=None,
        generator=torch.nn.Identity(),
        rng_state=lambda: {},
    )
    order = SimpleNamespace(total_steps=10, steps_per_epoch=5)
    watch = Stopwatch(TrainClock("wall", torch.device("cpu")))
    return Run(None, Dist(rank=0 if main else 1), gan, order, None, tmp_path, watch, None)


class _Recorder:
    """A hook that records the steps it observed and the steps it ran after."""

    def __init__(self, cadence: Cadence, *, observes: bool = False):
        self.cadence, self.ran, self.seen = cadence, [], []
        if observes:
            self.observe = lambda view: self.seen.append(view.step)

    def on_step(self, view):
        self.ran.append(view.step)


def _drive(hooks, steps: int, *, main: bool = True, last_at: int | None = None, passed_at=(), run=None):
    """Steps 1..steps through a runner, as the loop does; ``passed_at``: steps whose time cadences
    have passed on another process (OR-ed in as Dist.any would)."""
    run = run or _run(main=main)
    runner = HookRunner(hooks)
    for s in range(1, steps + 1):
        passed = [p or s in passed_at for p in runner.minutes_passed()]
        runner.after_step(run, StepEnd(s, {"loss": 0.5}, 1, last=s == (last_at or steps)), passed)
    return runner


def test_a_hook_runs_every_n_steps_and_after_the_last_whatever_its_number():
    every3, never_at_end = _Recorder(Cadence(steps=3)), _Recorder(Cadence(steps=3, at_end=False))
    _drive([every3, never_at_end], 7)
    assert every3.ran == [3, 6, 7] and never_at_end.ran == [3, 6]


def test_observe_sees_every_step_and_main_only_hooks_skip_other_processes():
    logging, validation = (
        _Recorder(Cadence(steps=2), observes=True),
        _Recorder(Cadence(steps=1, main_only=True)),
    )
    _drive([logging, validation], 5, main=False)
    assert logging.seen == [1, 2, 3, 4, 5] and logging.ran == [2, 4, 5]
    assert validation.ran == []
    main = _Recorder(Cadence(steps=1, main_only=True))
    _drive([main], 3, main=True)
    assert main.ran == [1, 2, 3]


def test_a_time_cadence_runs_when_its_minutes_pass_on_any_process_and_restarts_then():
    tiny, long = _Recorder(Cadence(minutes=0.0)), _Recorder(Cadence(minutes=60.0))
    runner = _drive([tiny, long], 4, passed_at={2})
    assert tiny.ran == [1, 2, 3, 4]  # passed on this process after every step
    assert long.ran == [2, 4]  # another process's clock said so at step 2; the end at 4
    assert runner.minutes_passed() == [True, False]  # 60 minutes restarted at step 4


def test_the_runner_asks_time_of_the_hooks_in_order_and_checks_the_answers_count():
    hooks = [_Recorder(Cadence(steps=1)), _Recorder(Cadence(minutes=0.0))]
    runner = HookRunner(hooks)
    assert runner.minutes_passed() == [False, True]  # no minutes: never by time
    with pytest.raises(ValueError):
        runner.after_step(_run(), StepEnd(1, {}, 1, last=False), [True])


# -- what a hook sees of the run, and what it changes ------------------------------------------------


class _Assigns:
    """A hook of the earlier design's habits: it writes the run's fields itself."""

    cadence = Cadence(steps=1)

    def on_step(self, view):
        view.saved_at = view.step


def test_a_hook_sees_a_narrow_read_only_view_and_cannot_assign_the_run():
    run = _run()
    with pytest.raises(dataclasses.FrozenInstanceError):
        _drive([_Assigns()], 1, run=run)
    assert run.saved_at == 0
    view = run.view(StepEnd(3, {"loss": 0.5}, 4, last=False))
    assert (view.step, view.samples, view.last, view.lr, view.total_steps) == (3, 4, False, 2e-5, 10)
    with pytest.raises(TypeError):
        view.terms["loss"] = 0.0  # the step's terms are read-only too
    for field in ("gan", "dist", "order", "watch", "run_id", "made_with"):
        assert not hasattr(view, field), f"the view hands hooks the run's {field}"


class _Saves:
    """A hook that says it wrote a checkpoint at each step it runs after."""

    def __init__(self, steps: int):
        self.cadence = Cadence(steps=steps, at_end=False)

    def on_step(self, view):
        return RunChange(saved_at=view.step)


def test_what_a_hook_returns_is_applied_to_the_run_before_the_next_hook_runs():
    run, later = _run(), _Recorder(Cadence(steps=1))
    later.on_step = lambda view: later.ran.append((view.step, view.saved_at))
    _drive([_Saves(2), later], 5, run=run)
    assert run.saved_at == 4  # the last step it ran after
    assert later.ran == [(1, 0), (2, 2), (3, 2), (4, 4), (5, 4)]
    wrong = _Recorder(Cadence(steps=1))
    wrong.on_step = lambda view: {"saved_at": view.step}  # a change must be a RunChange
    with pytest.raises(TypeError, match="RunChange"):
        _drive([wrong], 1)


def test_a_hook_of_the_earlier_design_is_refused_with_what_to_write_instead():
    legacy = SimpleNamespace(cadence=Cadence(steps=2), after_step=lambda run, end: None)
    with pytest.raises(TypeError, match=r"after_step\(run, end\), which went in 0.2.0: define on_step"):
        HookRunner([legacy])
    with pytest.raises(TypeError, match="no on_step"):
        HookRunner([SimpleNamespace(cadence=Cadence())])
