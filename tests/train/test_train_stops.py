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

from conftest import run_cli, run_cli_here
from svbrdf_train.training.checkpoint import load_checkpoint

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
    assert "the checkpoint of step 1 (" in r.stderr  # the step its hook returned (RunChange)
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


@pytest.mark.slow
def test_a_second_fit_on_a_running_fits_folder_is_refused_naming_its_pid(tmp_path):
    """Two fits on one --out (new or --resume) would mix their checkpoints: while one runs, the
    other is refused in one line naming the holder's PID; once the holder is dead (SIGKILL
    leaves its lock file behind) the lock is taken over and the fit resumes."""
    args = (*SMOKE, "--no-track", "--set", "train.epochs=1000", "--max-steps", "100000",
            "--set", "train.checkpoint_every=2", "--set", "train.validate_every=1000")  # fmt: skip
    proc = _start([*args, "--out", "busy"], tmp_path)
    try:
        _wait_for_checkpoint(proc, tmp_path / "busy")
        lock = tmp_path / "busy" / ".fit.lock"
        assert lock.read_text().strip() == str(proc.pid)
        for again in ([*args, "--out", "busy", "--force"], [*args, "--out", "busy", "--resume"]):
            second = run_cli(*again, cwd=tmp_path, timeout=120)
            assert second.returncode == 2, second.stderr
            lines = second.stderr.strip().splitlines()
            assert len(lines) == 1 and "Traceback" not in second.stderr, second.stderr
            assert f"PID {proc.pid}" in lines[0] and "busy" in lines[0], lines[0]
        assert proc.poll() is None, "the refused fits must not have stopped the running one"
    finally:
        proc.kill()
        proc.communicate()
    assert lock.exists(), "SIGKILL leaves the lock file of a dead process"
    step = load_checkpoint(tmp_path / "busy" / "last.pt")["step"]
    resumed = run_cli("fit", "--resume", "--no-track", "-q", "--max-steps", str(step + 2), "--out", "busy",
                      cwd=tmp_path, timeout=120)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    assert not lock.exists(), "a fit removes its lock file when it ends"


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_predict_stopped_by_a_signal_exits_130_with_the_summary_of_the_photos_done(tmp_path, sig):
    """Ctrl-C and SIGTERM alike stop a batch of photos with exit 130 (not click's "Aborted!", 1),
    one line naming the photo not written, and summary.json for the photos done before it."""
    import threading

    from svbrdf_render import write_image
    from svbrdf_render.formats.mapfiles import linear_to_srgb
    from svbrdf_train.data import ProceduralMaterials

    fit = run_cli("fit", "--recipe", "ours", "--size", "smoke", "-q", "--no-track", "--out", "fit",
                  cwd=tmp_path)  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    materials = ProceduralMaterials(4, 256, seed=5)
    photos = [tmp_path / f"p{i}.png" for i in range(4)]
    for i, photo in enumerate(photos):
        write_image(photo, linear_to_srgb(materials[i]["input"]))
    photos = [str(p) for p in photos]
    args = ["predict", *photos, "--checkpoint", "fit/last.pt", "--refine", "300", "-o", "maps"]
    proc = _start(args, tmp_path)
    watchdog = threading.Timer(300, proc.kill)  # a killing bound: neither the batch nor the stop may hang
    watchdog.start()
    try:
        first = proc.stdout.readline().strip()  # the folder of the first photo captured
        assert first.endswith("p0"), first
        proc.send_signal(sig)
        out, err = proc.communicate()
    finally:
        watchdog.cancel()
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Aborted" not in err, err
    stopped = [line for line in err.splitlines() if "interrupted" in line]
    assert len(stopped) == 1 and "not written" in stopped[0], err
    done = [first, *out.split()]
    summary = json.loads((tmp_path / "maps" / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert [e["name"] for e in summary["entries"]] == [os.path.basename(d) for d in done]
    assert summary["photos"] == len(done) < 4
    assert not list((tmp_path / "maps").rglob(".*.tmp")), "a temporary file was left behind"


@pytest.mark.slow
def test_a_deleted_run_is_refused_by_resume_predict_init_and_bench_in_one_line(tmp_path):
    """MLflow keeps a deleted run's artifacts and takes its metrics until the trash is emptied:
    each command that would read or continue it says so instead, and what to do."""
    from mlflow import MlflowClient

    from svbrdf_render import write_image
    from svbrdf_render.formats.mapfiles import linear_to_srgb
    from svbrdf_train.data import ProceduralMaterials

    env = {"MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}"}
    done = run_cli(*SMOKE, "--max-steps", "1", "--out", "fit", cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stderr
    run_id = json.loads((tmp_path / "fit" / "last.json").read_text())["run_id"]
    client = MlflowClient(env["MLFLOW_TRACKING_URI"])
    client.delete_run(run_id)
    write_image(tmp_path / "photo.png", linear_to_srgb(ProceduralMaterials(1, 64, seed=3)[0]["input"]))
    commands = {  # predict and bench in fresh processes; fit's two refusals here (no 2.5 s of imports)
        "resume": ["fit", "--resume", "-q", "--max-steps", "2", "--out", "fit"],
        "predict": [sys.executable, "-m", "svbrdf_train", "predict", "photo.png", "--run", run_id, "-o", "maps"],
        "init": [*SMOKE, "--init", run_id, "--out", "again"],
        "bench": [sys.executable, "-m", "svbrdf_bench", "run", "--models", "ours", "--size", "smoke",
                  "--from-runs", run_id, "-o", "bench"],
    }  # fmt: skip
    for name, argv in commands.items():
        if argv[0] == sys.executable:
            refused = subprocess.run(
                argv, cwd=tmp_path, env={**os.environ, **env}, capture_output=True, text=True, timeout=300
            )
        else:
            refused = run_cli_here(*argv, cwd=tmp_path, env=env)
        lines = refused.stderr.strip().splitlines()
        assert refused.returncode == 2 and len(lines) == 1, (name, refused.stderr)
        assert f"MLflow run {run_id} was deleted" in lines[0] and "mlflow runs restore" in lines[0], lines[0]
    assert client.get_run(run_id).info.status == "FINISHED", "the refused resume changed the run"
    assert not (tmp_path / "maps").exists() and not (tmp_path / "again" / "last.pt").exists()
    client.restore_run(run_id)
    resumed = run_cli("fit", "--resume", "-q", "--max-steps", "2", "--out", "fit", cwd=tmp_path, env=env)
    assert resumed.returncode == 0, resumed.stderr
    assert load_checkpoint(tmp_path / "fit" / "last.pt")["step"] == 2


def test_a_time_budget_the_step_budget_ends_long_before_is_warned_of_at_the_start(tmp_path):
    """The smoke size stops after 2 steps (train.max_steps=2): --max-minutes 3 is never reached,
    and the fit says so after its first step, naming both settings."""
    done = run_cli(*SMOKE, "--no-track", "--max-minutes", "3", "--out", "short", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    warned = [line for line in done.stderr.splitlines() if "will not be reached" in line]
    assert len(warned) == 1, done.stderr
    assert "train.max_minutes=3" in warned[0] and "train.max_steps=2" in warned[0] and "--max-steps" in warned[0]
    # a step budget far beyond the time budget: the time budget ends the fit, no warning
    long = run_cli(*SMOKE, "--no-track", "--max-minutes", "0.05", "--set", "train.max_steps=null",
                   "--set", "train.epochs=100000", "--out", "long", cwd=tmp_path)  # fmt: skip
    assert long.returncode == 0, long.stderr
    assert "time budget of 0.05 min reached" in long.stderr + long.stdout
    assert "will not be reached" not in long.stderr
