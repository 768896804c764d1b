"""Fits that stop: killed and resumed, interrupted, failed on a NaN; and fits on two processes.

Each test runs ``python -m svbrdf_train fit`` (or torchrun) in its own process, as a user would.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from conftest import run_cli
from svbrdf_train.checkpoint import load_checkpoint

SMOKE = ("fit", "--recipe", "ours", "--size", "smoke", "-q", "--experiment", "tests-stops")


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def _tensors(state, prefix=""):
    """Every tensor of a checkpoint, by dotted path (weights, Adam moments, RNG states)."""
    if isinstance(state, torch.Tensor):
        yield prefix, state
    elif isinstance(state, dict):
        for k, v in state.items():
            yield from _tensors(v, f"{prefix}.{k}")
    elif isinstance(state, (list, tuple)):
        for i, v in enumerate(state):
            yield from _tensors(v, f"{prefix}[{i}]")


def _assert_same_training_state(a, b):
    for key in ("generator", "discriminator", "optimizers", "rng", "step"):
        ta, tb = dict(_tensors(a[key])), dict(_tensors(b[key]))
        assert ta.keys() == tb.keys()
        different = [k for k in ta if not torch.equal(ta[k], tb[k])]
        assert not different, f"{key}: {different[:5]}"
    assert a["step"] == b["step"]
    assert a["schedule"] == b["schedule"]


def _start(args, cwd):
    return subprocess.Popen(
        [sys.executable, "-m", "svbrdf_train", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_checkpoint(proc, folder, timeout=120.0) -> int:
    """The step of the first checkpoint the running fit writes."""
    summary = folder / "last.json"
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if summary.is_file():
            try:
                return json.loads(summary.read_text())["step"]
            except (ValueError, KeyError):
                pass  # being replaced at this instant
        if proc.poll() is not None:
            raise AssertionError(f"the fit ended before its first checkpoint: {proc.communicate()}")
        time.sleep(0.01)
    proc.kill()
    raise AssertionError("no checkpoint within the timeout")


# 30 steps over 8 epochs of 4, a checkpoint every 2, D every 2 steps: long enough to be killed
# mid-way, short enough for CI.
LONG = (
    *SMOKE,
    "--set",
    "train.epochs=8",
    "--max-steps",
    "30",
    "--set",
    "train.checkpoint_every=2",
    "--set",
    "optim.g_steps_per_d=2",
    "--set",
    "train.validate_every=10",
)


@pytest.mark.slow
def test_sigkill_then_resume_reaches_the_same_weights_bitwise(tmp_path):
    """A fit SIGKILLed mid-way and resumed ends with the weights, Adam states and RNG states
    of an uninterrupted fit, bit for bit, and continues the same MLflow run."""
    whole = run_cli(*LONG, "--out", "whole", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr

    proc = _start([*LONG, "--out", "cut"], tmp_path)
    step = _wait_for_checkpoint(proc, tmp_path / "cut")
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    killed = load_checkpoint(tmp_path / "cut" / "last.pt")
    assert step <= killed["step"] < 30, "the kill must land mid-way"
    run_id = killed["run_id"]
    assert _client().get_run(run_id).info.status == "RUNNING"  # nobody could mark it
    # what a kill in the middle of a checkpoint write leaves (the instant cannot be aimed at)
    leftover = tmp_path / "cut" / f".last.pt.{proc.pid}.tmp"
    leftover.write_bytes(b"half a checkpoint")

    resumed = run_cli(*LONG, "--out", "cut", "--resume", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert not list((tmp_path / "cut").rglob("*.tmp")), "the resume left a temporary file"
    assert f"at step {killed['step']}" in resumed.stderr

    a = load_checkpoint(tmp_path / "whole" / "last.pt")
    b = load_checkpoint(tmp_path / "cut" / "last.pt")
    assert a["step"] == b["step"] == 30
    _assert_same_training_state(a, b)
    assert b["run_id"] == run_id
    run = _client().get_run(run_id)
    assert run.info.status == "FINISHED"
    assert run.data.tags["svbrdf.resumed_at"] == str(killed["step"])
    assert max(m.step for m in _client().get_metric_history(run_id, "train/loss")) == 30


@pytest.mark.slow
def test_ctrl_c_saves_marks_killed_and_resume_finishes(tmp_path):
    proc = _start([*LONG, "--out", "int"], tmp_path)
    _wait_for_checkpoint(proc, tmp_path / "int")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    state = load_checkpoint(tmp_path / "int" / "last.pt")
    assert f"stopped by SIGINT at step {state['step']}" in err  # saved where it stopped
    assert "Traceback" not in err
    assert _client().get_run(state["run_id"]).info.status == "KILLED"

    resumed = run_cli(*LONG, "--out", "int", "--resume", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert load_checkpoint(tmp_path / "int" / "last.pt")["step"] == 30
    assert _client().get_run(state["run_id"]).info.status == "FINISHED"


def test_non_finite_loss_stops_names_step_and_term_and_keeps_last_good_checkpoint(tmp_path):
    """A learning rate of 1e30 blows the weights up after the first step: the fit stops at step 2,
    says which term went non-finite, leaves the step-1 checkpoint and marks the run FAILED."""
    r = run_cli(
        *SMOKE,
        "--out",
        "nan",
        "--set",
        "optim.lr=1e30",
        "--set",
        "train.checkpoint_every=1",
        "--max-steps",
        "4",
        cwd=tmp_path,
    )
    assert r.returncode == 1, r.stderr
    assert "non-finite loss at step 2: term '" in r.stderr
    assert "Traceback" not in r.stderr
    state = load_checkpoint(tmp_path / "nan" / "last.pt")
    assert state["step"] == 1
    assert all(torch.isfinite(t).all() for _, t in _tensors(state["generator"]))
    assert _client().get_run(state["run_id"]).info.status == "FAILED"


@pytest.mark.slow
def test_two_cpu_processes_with_ddp_match_one_process_with_the_whole_batch(tmp_path):
    """torchrun, 2 processes x batch 1 (gloo) against 1 process x batch 2: the same samples and
    light/view configurations per step, gradients averaged by DDP, so the weights agree up to
    float reduction order. Only rank 0 logs: one MLflow run."""
    common = (*SMOKE, "--set", "train.epochs=3", "--max-steps", "6", "--set", "generator.config.dropout=0")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    ddp = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node=2",
            "-m",
            "svbrdf_train",
            *common,
            "--set",
            "train.batch=1",
            "--out",
            "ddp",
            "--run-name",
            "ddp-test",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ddp.returncode == 0, ddp.stderr[-3000:]
    one = run_cli(
        *common, "--set", "train.batch=2", "--out", "one", cwd=tmp_path, env={"OMP_NUM_THREADS": "1"}
    )
    assert one.returncode == 0, one.stderr

    a = load_checkpoint(tmp_path / "ddp" / "last.pt")
    b = load_checkpoint(tmp_path / "one" / "last.pt")
    assert a["world_size"] == 2 and len(a["rng"]) == 2 and a["step"] == b["step"] == 6
    torch.manual_seed(0)
    from svbrdf_models import create_generator

    init = create_generator("ours", {"preset": "tiny", "dropout": 0}).state_dict()
    diff = sum((a["generator"][k] - b["generator"][k]).square().sum() for k in init).sqrt()
    moved = sum((b["generator"][k] - init[k]).square().sum() for k in init).sqrt()
    assert moved > 0
    assert diff < 0.01 * moved, (float(diff), float(moved))

    runs = _client().search_runs(
        [_client().get_experiment_by_name("tests-stops").experiment_id],
        filter_string="attributes.run_name = 'ddp-test'",
    )
    assert len(runs) == 1 and runs[0].data.tags["world_size"] == "2"

    again = run_cli(
        *common, "--set", "train.batch=1", "--out", "ddp", "--resume", "--max-steps", "8", cwd=tmp_path
    )
    assert again.returncode == 2
    assert "written by 2 process(es), resumed with 1" in again.stderr
