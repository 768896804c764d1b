"""The report's verdicts, from per-sample figures made up here: beats / worse / within noise against
``mean``, the headline in words, the clock note, and that baselines stay out of the cost pairs."""

from __future__ import annotations

import numpy as np

from svbrdf_bench.report import COLUMNS, ModelEntry, Report, clock_note, headline, table_lines, terminal
from svbrdf_bench.report.tables import against_table, cost_table, time_table

N = 40


def _entry(label: str, rmse: dict[str, np.ndarray], *, baseline=False, clock=None) -> ModelEntry:
    per_sample = {f"rmse/{c}": v for c, v in rmse.items()}
    figures = {"time/latency_ms": 1.0, "model/params": 0.0 if baseline else 1e5}
    if not baseline:
        figures |= {"time/train_s": 60.0, "time/train_steps_wall_s": 75.0, "time/train_ms_per_step": 10.0}
    return ModelEntry(
        label, f"run-{label}", f"run-{label}", per_sample, figures, baseline=baseline, clock=clock
    )


def _report(test_set="21 Des18 samples of des18-dev (whole tiles resized to 128 px)", baselines="mean,photo"):
    rng = np.random.default_rng(0)
    base = {c: 0.1 + 0.02 * rng.random(N) for c in COLUMNS}
    noise = {c: 0.001 * rng.standard_normal(N) for c in COLUMNS}
    good = {c: base[c] - 0.03 for c in COLUMNS}  # better than mean everywhere
    mixed = {  # better on normal, worse on diffuse, indistinguishable elsewhere
        "normal": base["normal"] - 0.03,
        "diffuse": base["diffuse"] + 0.05,
        **{c: base[c] + noise[c] for c in ("roughness", "specular", "render")},
    }
    models = [
        _entry("good", good, clock="cpu"),
        _entry("mixed", mixed, clock=None),
        _entry("mean", base, baseline=True),
        _entry("photo", {c: base[c] + 0.01 for c in COLUMNS}, baseline=True),
    ]
    return Report("parent", "quick", test_set, "LPIPS skipped", "2.0 min", models, baselines=baselines)


def test_verdicts_against_mean_are_the_paired_bootstrap_signs():
    report = _report()
    verdicts = {(r["model"], r["column"]): r["verdict"] for r in report.against_reference()}
    assert {m for m, _ in verdicts} == {"good", "mixed"}  # trained models only, never the baselines
    assert all(verdicts["good", c] == "beats" for c in COLUMNS)
    assert verdicts["mixed", "normal"] == "beats" and verdicts["mixed", "diffuse"] == "worse"
    assert all(verdicts["mixed", c] == "within noise" for c in ("roughness", "specular", "render"))
    for r in report.against_reference():
        assert r["low"] <= r["rmse_difference"] <= r["high"]
    # The share of mean's RMSE, which is how a target like "15% better than mean" reads.
    good_normal = next(
        r for r in report.against_reference() if r["model"] == "good" and r["column"] == "normal"
    )
    ref = next(e for e in report.models if e.label == "mean")
    assert abs(good_normal["relative"] + 0.03 / ref.per_sample["rmse/normal"].mean()) < 1e-9


def test_headline_says_in_words_who_does_not_beat_mean():
    report = _report()
    good, mixed = headline(report)
    assert good.startswith("good beats the constant-map baseline `mean` on every map and on renderings")
    assert mixed.startswith(
        "mixed does NOT beat the constant-map baseline `mean` on diffuse, roughness, specular, render: "
        "it has learned nothing that transfers there"
    )
    assert "worse on diffuse" in mixed and "within noise on roughness, specular, render" in mixed
    text = terminal(report).splitlines()
    assert text[0].startswith("svbrdf-bench: good, mixed, mean (baseline), photo (baseline)")
    assert text[1:3] == [good, mixed]
    # On synthetic test images the claim is not about transfer.
    synthetic = headline(_report(test_set="32 procedural materials (seed 20221)"))[1]
    assert "even on synthetic test images" in synthetic and "transfers" not in synthetic


def test_without_baselines_the_headline_says_nothing_is_compared():
    report = _report(baselines="-")
    report.models = [e for e in report.models if not e.baseline]
    assert report.against_reference() == [] and table_lines(against_table(report), False) == []
    assert headline(report)[0].startswith("No baseline was evaluated (--no-baselines)")


def test_costs_pair_trained_models_only_and_say_when_they_do_not_beat_mean():
    report = _report()
    costs = report.costs()
    assert {(c["model"], c["versus"]) for c in costs} == {("good", "mixed")}
    lines = table_lines(cost_table(report), False)
    assert lines[0] == "What accuracy costs (trained models)"
    assert any(
        line.startswith("mixed does not beat the constant-map baseline `mean` on renderings")
        for line in lines
    )


def test_clock_note_reads_the_tag_and_says_wall_clock_when_absent():
    report = _report()
    note = clock_note(report)
    assert "good: the CPU clock (process CPU time divided by torch threads)" in note
    assert "mixed: the wall clock (none recorded)" in note
    for e in report.trained:
        e.clock = "cuda"
    assert clock_note(report) == (
        "training time budgeted and reported on the GPU clock (wall time with the device synchronised)"
    )


def test_time_table_shows_budget_and_wall_time_and_dashes_for_baselines():
    table = table_lines(time_table(_report()), False)
    head = table[1]
    assert "train time, budget clock (s)" in head and "train wall (s)" in head
    good = table[3].split()
    assert good[:3] == ["good", "60.0", "75.0"]
    for row in table[5:]:
        assert row.split()[2:4] == ["-", "-"]  # the baselines trained for no time
