"""A damaged checkpoint is refused, not resumed (issue 47): ``save_checkpoint`` records the
file's SHA-256 beside it, and every load checks it; zip CRCs alone let 64 zeroed bytes in a
tensor through."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from svbrdf_train.cli import cli
from svbrdf_train.errors import CheckpointError
from svbrdf_train.recipe import load_recipe
from svbrdf_models.modelfile.modelcheck import file_sha256
from svbrdf_train.training.checkpoint import load_checkpoint
from svbrdf_train.training.trainer import FitOptions, fit


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "run"
    recipe = load_recipe("ours", "smoke", {"train.max_steps": 1, "train.epochs": 100})
    fit(recipe, FitOptions(out=out, progress=False, track=False))
    return out


def _zero_middle(path, count=64):
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + count] = bytes(count)
    path.write_bytes(bytes(data))


def test_the_checksum_is_recorded_beside_each_checkpoint(fitted):
    for name in ("last", "weights"):
        summary = json.loads((fitted / f"{name}.json").read_text())
        assert summary["sha256"] == file_sha256(fitted / f"{name}.pt")


def test_a_checkpoint_with_zeroed_bytes_is_refused(fitted, tmp_path):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(fitted, copy)
    load_checkpoint(copy / "last.pt")  # whole: it loads
    _zero_middle(copy / "last.pt")
    with pytest.raises(CheckpointError, match="SHA-256"):
        load_checkpoint(copy / "last.pt")
    result = CliRunner().invoke(cli, ["fit", "--out", str(copy), "--resume", "--no-track"])
    assert result.exit_code == 2, result.output
    assert "damaged" in result.output and "Traceback" not in result.output


def test_a_checkpoint_without_a_recorded_checksum_still_loads(fitted, tmp_path):
    import shutil

    shutil.copy(fitted / "weights.pt", tmp_path / "w.pt")  # no summary beside it
    assert load_checkpoint(tmp_path / "w.pt")["step"] == 1
