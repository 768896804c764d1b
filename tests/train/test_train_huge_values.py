"""Values past any sane size that reached torch (issue 47): ``--threads 1099511627776`` on
``fit`` (``ValueError: Overflow when unpacking long``) and ``data.count: 1000000000000`` (torch's
allocation error in ``training/order.py``, once the fit had started). Both are refused in one
line naming the flag or field and the bound, exit 2, before any work."""

from __future__ import annotations

import pytest

from svbrdf_train.cli import main

SMOKE = ["recipes", "ours", "--size", "smoke"]
HUGE = "1000000000000"


def _one_line(capsys, argv) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, (argv, code, captured.err)
    assert "Traceback" not in captured.err + captured.out
    errors = [line for line in captured.err.splitlines() if "error:" in line.lower()]
    assert len(errors) == 1, captured.err
    return errors[0]


def test_fit_refuses_threads_past_any_machine(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["fit", "--recipe", "ours", "--size", "smoke", "--out", "run", "--threads", "1099511627776"]
    line = _one_line(capsys, argv)
    assert "'--threads'" in line and "1<=x<=4096" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("items", "fragments"),
    [
        (["data.count=" + HUGE], ["count must be at most 100_000_000 samples", HUGE]),
        (["data.validation=" + HUGE], ["validation must be at most 100_000_000 samples", HUGE]),
        (["data.source=mix", f"data.mix=[{{source: procedural, weight: 1, count: {HUGE}}}]"],
         ["mix[0].count must be at most 100_000_000 samples", HUGE]),  # fmt: skip
    ],
)
def test_sample_counts_past_the_bound_are_refused_when_the_recipe_loads(items, fragments, capsys, tmp_path,
                                                                         monkeypatch):  # fmt: skip
    monkeypatch.chdir(tmp_path)
    line = _one_line(capsys, [*SMOKE, *(a for item in items for a in ("--set", item))])
    assert line.startswith("svbrdf-train: error: ")
    for fragment in fragments:
        assert fragment in line, (fragment, line)


def test_fit_refuses_a_huge_count_before_training(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["fit", "-q", "--no-track", "--recipe", "ours", "--size", "smoke", "--out", "run", "--set", "data.count=" + HUGE]
    assert "count must be at most 100_000_000" in _one_line(capsys, argv)
    assert not (tmp_path / "run").exists()


def test_the_bound_itself_loads(capsys, tmp_path, monkeypatch):
    from svbrdf_train.recipe.values import MAX_SAMPLES

    monkeypatch.chdir(tmp_path)
    assert main([*SMOKE, "--set", f"data.count={MAX_SAMPLES}", "--set", f"data.validation={MAX_SAMPLES}"]) == 0
    capsys.readouterr()
