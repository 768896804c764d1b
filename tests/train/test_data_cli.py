"""``svbrdf-train data make | import | info``: shards from the command line, refusals and errors."""

from __future__ import annotations

import dataclasses
import json
import re
import signal
import subprocess
import sys
import time

import h5py
import pytest
import torch
from click.testing import CliRunner

from conftest import random_svbrdf
from svbrdf_render import write_des18
from svbrdf_train.cli import cli
from svbrdf_train.data import procedural
from svbrdf_train.data.real.des18 import Des18Folder
from svbrdf_train.data.shards import ShardDataset, inspect_shard
from svbrdf_train.data.simulated_photo import PhotoSettings


def _run(*args):
    result = CliRunner().invoke(cli, ["data", *map(str, args)])
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


@pytest.fixture
def des18_folder(tmp_path):
    folder = tmp_path / "strips"
    folder.mkdir()
    for i in range(5):
        maps = random_svbrdf(1, 64, seed=i)
        photo = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(i))
        write_des18(folder / f"{4 * i:07d};MatAXMatB;0X1.png", photo, maps)
    return folder


# -- make ------------------------------------------------------------------------------------


def test_make_writes_the_procedural_samples(tmp_path):
    out = tmp_path / "train.h5"
    result = _run("make", "--count", 5, "--resolution", 32, "--seed", 2, "--batch", 2, "--out", out)
    assert result.exit_code == 0, result.output
    assert f"wrote {out}: 5 samples at 32x32, 8-bit" in result.stdout
    info = inspect_shard(out)
    assert (info.count, info.resolution, info.bits) == (5, 32, 8)
    assert info.attrs["source"] == "procedural" and info.attrs["seed"] == 2
    assert info.attrs["generator_version"] == procedural.GENERATOR_VERSION
    assert info.attrs["families"] == list(procedural.FAMILIES) and info.attrs["mix"] == 0.3
    assert json.loads(info.attrs["photo"]) == json.loads(json.dumps(dataclasses.asdict(PhotoSettings())))
    data = ShardDataset(out)
    expected = procedural.ProceduralMaterials(5, 32, 2).batch([0, 1, 2, 3, 4])
    assert [data[i]["name"] for i in range(5)] == [f"procedural:2:{i}" for i in range(5)]
    for i in range(5):
        assert float((data[i]["maps"][3:] - expected["maps"][i, 3:]).abs().max()) <= 0.5 / 255 + 1e-6
        assert float((data[i]["input"] - expected["input"][i].clamp(0, 1)).abs().max()) <= 0.5 / 255 + 1e-6


def test_make_refuses_to_overwrite_without_force(tmp_path):
    out = tmp_path / "train.h5"
    assert _run("make", "-n", 2, "-r", 16, "-o", out).exit_code == 0
    before = out.read_bytes()
    result = _run("make", "-n", 3, "-r", 16, "-o", out)
    assert result.exit_code == 2
    assert "already exists; pass --force" in result.stderr
    assert out.read_bytes() == before
    result = _run("make", "-n", 3, "-r", 16, "--bits", 16, "-o", out, "--force")
    assert result.exit_code == 0, result.output
    assert inspect_shard(out).count == 3 and inspect_shard(out).bits == 16


def test_make_unknown_family_lists_the_families(tmp_path):
    result = _run("make", "-n", 2, "-r", 16, "-o", tmp_path / "x.h5", "--family", "marble")
    assert result.exit_code == 2
    assert "marble" in result.stderr and "choose from stone, tiles" in result.stderr
    assert not (tmp_path / "x.h5").exists()


def test_make_interrupted_leaves_no_file(tmp_path, monkeypatch):
    calls = []
    real_batch = procedural.ProceduralMaterials.batch

    def interrupted(self, indices):
        calls.append(indices)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_batch(self, indices)

    monkeypatch.setattr(procedural.ProceduralMaterials, "batch", interrupted)
    result = _run("make", "-n", 4, "-r", 16, "--batch", 2, "-o", tmp_path / "x.h5")
    assert result.exit_code == 130 and "interrupted" in result.stderr and "Aborted" not in result.output
    assert list(tmp_path.iterdir()) == []


def _dead_pid() -> int:
    """A process id that no running process has (the PID of a child that has ended)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_make_stopped_by_a_signal_exits_130_and_leaves_nothing(tmp_path, sig):
    """Ctrl-C and SIGTERM alike, in a real process: exit 130, one line, no temporary file; and the
    temporary of an earlier run killed outright (SIGKILL) is removed by the next run."""
    out = tmp_path / "x.h5"
    stale = tmp_path / f".x.h5.{_dead_pid()}.tmp"
    stale.write_bytes(b"half a shard")
    proc = subprocess.Popen(
        [sys.executable, "-m", "svbrdf_train", "data", "make", "-n", "100000", "-r", "64", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        mine = tmp_path / f".x.h5.{proc.pid}.tmp"
        end = time.monotonic() + 120
        while not mine.exists() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.05)
        assert mine.exists(), "the shard was never started"
        assert not stale.exists(), "the stale temporary of a dead process was kept"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)  # a killing bound: the stop must not hang
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Aborted" not in err, err
    assert [line for line in err.splitlines() if "interrupted" in line] == [
        f"svbrdf-train: interrupted: {out} not written (left as it was)"
    ], err
    assert list(tmp_path.iterdir()) == []


def test_make_takes_a_stop_whose_interrupt_python_dropped(tmp_path, monkeypatch):
    """SIGTERM landing in a weakref callback loses its KeyboardInterrupt (seen: `data make` went on
    past the signal); the loop takes the stop after the batch in progress, as it would Ctrl-C."""
    from svbrdf_render.plumbing import processes

    real_batch = procedural.ProceduralMaterials.batch
    made = []

    def batch(self, indices):
        made.append(len(indices))
        if len(made) == 2:
            processes._STOP["signal"] = "SIGTERM"  # what the handler records before its raise is lost
        return real_batch(self, indices)

    monkeypatch.setattr(procedural.ProceduralMaterials, "batch", batch)
    out = tmp_path / "x.h5"
    result = _run("make", "--count", 40, "--resolution", 16, "--batch", 4, "--out", out)
    assert result.exit_code == 130, result.output
    assert made == [4, 4] and f"interrupted: {out} not written" in result.stderr
    assert list(tmp_path.iterdir()) == [] and processes._STOP["signal"] is None


# -- import ----------------------------------------------------------------------------------


def test_import_des18_folder_centre_crops(tmp_path, des18_folder):
    out = tmp_path / "test.h5"
    result = _run("import", des18_folder, "--out", out, "--crop", 32)
    assert result.exit_code == 0, result.output
    info = inspect_shard(out)
    assert (info.count, info.resolution) == (5, 32)
    assert info.attrs["source"] == "des18" and info.attrs["crop"] == "centre 32"
    assert info.attrs["source_folder"] == str(des18_folder.resolve())
    data, strips = ShardDataset(out), Des18Folder(des18_folder, split="test", crop=32)
    for i in range(5):
        assert data[i]["name"] == strips.files[i].name
        assert float((data[i]["maps"][3:] - strips[i]["maps"][3:]).abs().max()) < 1e-6  # both 8-bit
        assert float((data[i]["input"] - strips[i]["input"]).abs().max()) < 1e-6


def test_import_full_tiles_at_16_bits(tmp_path, des18_folder):
    out = tmp_path / "full.h5"
    assert _run("import", des18_folder, "-o", out, "--full", "--bits", 16).exit_code == 0
    info = inspect_shard(out)
    assert (info.count, info.resolution, info.bits) == (5, 64, 16)
    assert info.attrs["crop"] == "full tile"


def test_import_refuses_to_overwrite(tmp_path, des18_folder):
    out = tmp_path / "test.h5"
    out.write_bytes(b"precious")
    result = _run("import", des18_folder, "-o", out, "--crop", 32)
    assert result.exit_code == 2 and "--force" in result.stderr
    assert out.read_bytes() == b"precious"


def test_bad_folder_is_one_line_exit_2(tmp_path):
    (tmp_path / "empty").mkdir()
    for folder in (tmp_path / "empty", tmp_path / "nowhere"):
        result = _run("import", folder, "-o", tmp_path / "x.h5")
        assert result.exit_code == 2
        assert result.stderr.startswith("svbrdf-train: error: ") and str(folder) in result.stderr
        assert result.stderr.count("\n") == 1 and "Traceback" not in result.output
    assert not (tmp_path / "x.h5").exists()


def test_crop_larger_than_tiles_is_an_error(tmp_path, des18_folder):
    result = _run("import", des18_folder, "-o", tmp_path / "x.h5", "--crop", 100)
    assert result.exit_code == 2 and "smaller than the crop of 100" in result.stderr
    assert not (tmp_path / "x.h5").exists()


# -- info ------------------------------------------------------------------------------------


def test_info_prints_counts_and_provenance(tmp_path, des18_folder):
    out = tmp_path / "test.h5"
    _run("import", des18_folder, "-o", out, "--crop", 32)
    result = _run("info", out, "--check")
    assert result.exit_code == 0, result.output
    assert "5 at 32x32, 8-bit" in result.stdout
    assert re.search(r"^  source +des18$", result.stdout, re.M) and "all 5 samples decode" in result.stdout


def test_info_check_names_a_damaged_sample(tmp_path, des18_folder):
    out = tmp_path / "test.h5"
    _run("import", des18_folder, "-o", out, "--crop", 32)
    with h5py.File(out) as f:
        chunk = f["input"].id.get_chunk_info(3)
    with open(out, "r+b") as f:
        f.seek(chunk.byte_offset + chunk.size // 2)
        f.write(bytes(8))
    assert _run("info", out).exit_code == 0  # attributes alone look fine
    result = _run("info", "--check", out)
    assert result.exit_code == 2 and "sample 3 cannot be read" in result.stderr


def test_info_on_a_file_that_is_not_a_shard(tmp_path):
    (tmp_path / "x.h5").write_bytes(b"not hdf5 at all")
    result = _run("info", tmp_path / "x.h5")
    assert result.exit_code == 2 and "cannot be opened as HDF5" in result.stderr


@pytest.mark.parametrize("command", ["make", "import", "info"])
def test_help_teaches_with_examples(command):
    result = _run(command, "--help")
    assert result.exit_code == 0
    assert "Examples:" in result.stdout and f"svbrdf-train data {command}" in result.stdout
