"""Seeds and training budgets (``svbrdf-bench run --seeds N --steps 1,2``): a row per model, seed and
budget in MLflow and results.json, the report's "Across seeds and budgets" section rebuilt from
MLflow alone, the hierarchical bootstrap on made-up numbers, and the refusals.

One tiny benchmark (two recipes at the smoke size, 2 seeds, snapshots at steps 1 and 2, 4 test
images, no baselines) runs once per module; a second invocation reuses its fits of ``ours`` by
run id, at budgets one of which the fits never reached.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_bench.cli import cli
from svbrdf_bench.errors import BenchError
from svbrdf_bench.report import ModelEntry, Report, build_report, table_lines
from svbrdf_bench.report import seeds as section
from svbrdf_bench.report import seedstats as stats

TINY = ("--size", "smoke", "--test-count", "4", "--experiment", "tests-seeds", "--no-baselines")
LABELS = [f"{m} seed {s} @ {b}" for m in ("ours", "radn") for s in (0, 1) for b in ("1 step", "2 steps")]


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _children(parent_id: str) -> list:
    client = _client()
    return client.search_runs(
        [client.get_run(parent_id).info.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'"
    )


def _section_lines(text: str) -> list[str]:
    """The section: its table, an empty line, then its sentences up to the next empty line."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Across seeds and budgets"))
    gap = next(i for i in range(start, len(lines)) if not lines[i].strip())
    end = next((i for i in range(gap + 1, len(lines)) if not lines[i].strip()), len(lines))
    return lines[start:end]


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("seeds") / "report"
    result = _invoke("run", "--models", "ours,radn", "--seeds", "2", "--steps", "1,2", *TINY, "-o", out)
    assert result.exit_code == 0, result.output
    return out, result, json.loads((out / "results.json").read_text())["parent_run"]


# -- the benchmark --------------------------------------------------------------------------------


def test_a_row_per_model_seed_and_budget_each_scored_from_its_fit_s_snapshot(bench):
    _, result, parent_id = bench
    client = _client()
    params = client.get_run(parent_id).data.params
    assert params["seeds"] == "2" and params["train_budgets"] == "steps 1,2"
    children = _children(parent_id)
    rows = {c.data.tags["svbrdf.model"]: c for c in children if "svbrdf.model" in c.data.tags}
    assert sorted(rows) == sorted(LABELS)
    fits = {c.info.run_id: c for c in children if "svbrdf.model" not in c.data.tags}
    assert len(fits) == 4  # one fit per model and seed, not one per budget
    for label, row in rows.items():
        model, seed, budget = label.split(" ")[0], int(label.split(" ")[2]), label.split(" @ ")[1]
        tags = row.data.tags
        assert (tags["svbrdf.method"], tags["svbrdf.seed"], tags["svbrdf.budget"]) == (model, str(seed), budget)
        assert tags["svbrdf.snapshot"] == f"steps-{budget.split()[0]}.pt" and row.info.status == "FINISHED"
        fit = fits[tags["svbrdf.train_run"]]  # the fit, a child with no row of its own
        assert fit.data.tags["recipe"] == model and fit.data.tags["svbrdf.seed"] == str(seed)
        assert fit.data.params["train.seed"] == fit.data.params["data.seed"] == str(seed)
        assert fit.data.params["train.max_steps"] == "2"
        assert row.data.metrics["train/steps"] == int(budget.split()[0])  # the snapshot's step, not the fit's
    assert {len([r for r in rows.values() if r.data.tags["svbrdf.train_run"] == f]) for f in fits} == {2}
    for said in ("[1/4] training ours seed 0", "[4/4] training radn seed 1", "evaluating ours seed 1 @ 2 steps"):
        assert said in result.stderr


def test_results_json_names_each_row_s_seed_and_budget(bench):
    out, _, _ = bench
    records = {r["model"]: r for r in json.loads((out / "results.json").read_text())["models"]}
    assert sorted(records) == sorted(LABELS)
    for label, r in records.items():
        assert r["seed"] == int(label.split(" ")[2]) and r["budget"] == label.split(" @ ")[1]
    assert "seed" in (out / "results.csv").read_text().splitlines()[0].split(",")


def test_the_section_shows_each_model_and_budget_over_seeds(bench):
    out, result, _ = bench
    lines = _section_lines(result.stdout)
    assert lines[0].startswith("Across seeds and budgets (RMSE") and "between-seed standard deviation" in lines[0]
    assert lines[1].split()[:5] == ["model", "budget", "seeds", "train", "min"]
    assert [line.split()[:4] for line in lines[3:7]] == [
        ["ours", "1", "step", "0,1"], ["ours", "2", "steps", "0,1"], ["radn", "1", "step", "0,1"],
        ["radn", "2", "steps", "0,1"],
    ]  # fmt: skip
    assert all("±" in line and "[" in line for line in lines[3:7])  # spread and interval beside each mean
    words = "\n".join(lines[7:])
    assert "resamples drawing seeds, then test images" in words
    assert "At 2 steps: " in words and ("beats" in words or "within noise" in words)
    assert "ours from 1 step to 2 steps:" in words and "on the front" in words
    doc = json.loads((out / "results.json").read_text())["across_seeds"]
    assert [(c["model"], c["budget"], c["seeds"]) for c in doc["cells"]] == [
        ("ours", "1 step", [0, 1]), ("ours", "2 steps", [0, 1]), ("radn", "1 step", [0, 1]),
        ("radn", "2 steps", [0, 1]),
    ]  # fmt: skip
    for c in doc["cells"]:
        r = c["rmse"]["render"]
        assert r["low"] <= r["mean"] <= r["high"] and r["seed_min"] <= r["mean"] <= r["seed_max"]
    assert {(v["budget"], v["column"]) for v in doc["verdicts"]} == {
        (b, col) for b in ("1 step", "2 steps") for col in ("render", "normal", "diffuse", "roughness", "specular")
    }
    assert {g["model"] for g in doc["gains"]} == {"ours", "radn"} and doc["missed"] == []
    md = (out / "report.md").read_text()
    assert "## Across seeds and budgets" in md and "(accuracy_vs_training_time.png)" in md
    from svbrdf_render import read_image

    assert min(read_image(out / "accuracy_vs_training_time.png").shape[1:]) > 100


def test_the_section_rebuilds_from_mlflow_alone(bench, tmp_path):
    out, result, parent_id = bench
    again = _invoke("report", parent_id, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    assert _section_lines(again.stdout) == _section_lines(result.stdout)
    report = build_report(parent_id)
    assert table_lines(section.seeds_table(report), False) == _section_lines(result.stdout)
    assert (tmp_path / "again" / "accuracy_vs_training_time.png").is_file()
    # The rows of one fit share its learning curve: drawn once, on its last budget's row.
    curved = sorted(e.label for e in report.models if e.curve[0])
    assert curved == sorted(label for label in LABELS if label.endswith("2 steps"))


def test_reused_seeds_are_one_model_and_a_budget_not_reached_is_said(bench, tmp_path):
    """Two fits of ``ours`` given by run id (seeds 0 and 1) are seeds of one model; their snapshots
    come from MLflow, and the budget of 3 steps, which they never reached, is said, not dropped."""
    _, _, parent_id = bench
    fits = sorted((c for c in _children(parent_id) if "svbrdf.model" not in c.data.tags
                   and c.data.tags["recipe"] == "ours"), key=lambda c: c.data.tags["svbrdf.seed"])  # fmt: skip
    result = _invoke("run", "--from-runs", ",".join(f.info.run_id for f in fits), "--steps", "1,3", *TINY,
                     "-o", tmp_path / "r")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "] training" not in result.stderr  # reused, not trained
    assert "budgets of 1, 3 steps, each the snapshot of one fit per model and seed" in result.stdout
    doc = json.loads((tmp_path / "r" / "results.json").read_text())
    assert [(r["model"], r["seed"], r["budget"]) for r in doc["models"]] == [
        ("ours seed 0 @ 1 step", 0, "1 step"), ("ours seed 1 @ 1 step", 1, "1 step")
    ]  # fmt: skip
    missed = doc["across_seeds"]["missed"]
    assert [(m["model"], m["seed"], m["budget"]) for m in missed] == [("ours", 0, "3 steps"), ("ours", 1, "3 steps")]
    assert "ours seed 0: no row at 3 steps: the reused fit saved no snapshot at it" in result.stderr
    text = "\n".join(_section_lines(result.stdout))
    assert "Not reached: ours seed 1 @ 3 steps: the reused fit saved no snapshot at it" in text
    again = _invoke("report", doc["parent_run"])
    assert _section_lines(again.stdout) == _section_lines(result.stdout)  # read back from MLflow
    # The snapshot scored is the fit's own at step 1: the same figures as the first benchmark's row.
    first = {r["model"]: r for r in json.loads((bench[0] / "results.json").read_text())["models"]}
    assert doc["models"][1]["rmse_render"] == pytest.approx(first["ours seed 1 @ 1 step"]["rmse_render"])


# -- the hierarchical bootstrap, on made-up numbers -------------------------------------------------


def _seeds(n_seeds=3, n_units=30, offsets=None, shift=0.0, seed=0) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = 0.1 + 0.02 * rng.random(n_units)  # the materials: some harder than others
    offsets = offsets or [0.0] * n_seeds
    return {s: base + shift + offsets[s] + 0.001 * rng.standard_normal(n_units) for s in range(n_seeds)}


def test_a_constant_difference_beats_across_seeds():
    a, b = _seeds(seed=1), _seeds(seed=1, shift=0.01)
    d = stats.paired_seeds(a, b)
    assert d.high < 0 and not d.within_noise and d.mean == pytest.approx(-0.01, abs=1e-3)
    assert d.p_value < 0.05
    back = stats.paired_seeds(b, a)
    assert back.low > 0 and back.mean == pytest.approx(-d.mean)


def test_a_large_between_seed_spread_does_not_beat():
    """B is 0.01 worse on average, but its seeds scatter by +-0.05: the seeds cannot tell."""
    a = _seeds(seed=2)
    b = _seeds(seed=2, shift=0.01, offsets=[0.06, -0.05, 0.02])
    d = stats.paired_seeds(a, b)
    assert d.within_noise and d.low < 0 < d.high
    # the materials alone (one seed) would have called it
    assert not stats.paired_seeds({0: a[0]}, {0: b[0]}).within_noise


def test_more_seeds_do_not_shrink_what_the_materials_leave_uncertain():
    """Seeds and materials are crossed: copies of one seed on the same materials add no evidence
    about other materials, so the interval stays as wide as one seed's."""
    one = _seeds(n_seeds=1, seed=3)[0]
    width = np.subtract(*stats.hierarchical_bootstrap(one[None])[2:0:-1])
    copies = np.stack([one] * 5)
    assert np.subtract(*stats.hierarchical_bootstrap(copies)[2:0:-1]) == pytest.approx(width, rel=0.15)
    spread = copies + np.array([0.03, -0.02, 0.01, -0.03, 0.02])[:, None]  # seeds that disagree: wider
    assert np.subtract(*stats.hierarchical_bootstrap(spread)[2:0:-1]) > 1.5 * width


def test_the_hierarchical_bootstrap_s_edges():
    x = np.array([[0.1, 0.2, 0.3], [0.2, 0.3, 0.4]])
    mean, low, high = stats.hierarchical_bootstrap(x)
    assert mean == pytest.approx(0.25) and 0.1 < low < mean < high < 0.4
    assert stats.hierarchical_bootstrap(x) == stats.hierarchical_bootstrap(x)  # seeded
    assert stats.hierarchical_bootstrap([[0.5]]) == (0.5, 0.5, 0.5)
    assert stats.paired_seeds({0: x[0]}, {1: x[1]}) is None  # no seed in common
    for bad in (np.zeros(3), np.array([[np.nan, 1.0]])):
        with pytest.raises(BenchError, match="hierarchical_bootstrap"):
            stats.hierarchical_bootstrap(bad)


def _report(rows: list[tuple[str, int, float, dict]]) -> Report:
    models = []
    for method, seed, steps, values in rows:
        label = f"{method} seed {seed} @ {steps:g} steps"
        per_sample = {"rmse/render": values[seed], **{f"rmse/{m}": values[seed] / 2 for m in
                                                      ("normal", "diffuse", "roughness", "specular")}}  # fmt: skip
        e = ModelEntry(label, f"run-{label}", f"fit-{method}-{seed}", per_sample, {"time/train_s": steps * 6.0})
        e.seed, e.method, e.train_budget = seed, method, ("steps", steps)
        models.append(e)
    return Report("parent", "quick", "made up", "-", "-", models)


def test_the_section_s_verdicts_in_words():
    good, bad = _seeds(seed=4), _seeds(seed=4, shift=0.02)
    late = {s: v - 0.005 for s, v in good.items()}  # more steps help A, not B
    report = _report([("a", s, 10, good) for s in range(3)] + [("a", s, 40, late) for s in range(3)]
                     + [("b", s, 10, bad) for s in range(3)] + [("b", s, 40, bad) for s in range(3)])  # fmt: skip
    assert stats.shown(report)
    words = "\n".join(section.section_lines(report))
    assert "At 10 steps: a beats b on render RMSE by -0.0200" in words and "(3 seeds)" in words
    assert "a from 10 steps to 40 steps: -0.0050" in words and "gains" in words
    assert "b from 10 steps to 40 steps" in words and "it stops gaining after 10 steps" in words
    assert "on the front (trained no longer than, and better beyond noise than, every other): a @ 10 steps, a @ 40 steps" in words
    series = section.training_time_series(report)
    assert [(m, b) for m, b, _ in series["a"]] == [(1.0, "10 steps"), (4.0, "40 steps")]


def test_models_at_one_budget_in_minutes_cost_the_same_on_the_training_front():
    """A snapshot lands at the first step past the mark, so two models given 2 minutes measure
    2.00 and 2.01: neither is cheaper, and the one within noise is not dominated for it."""
    good = _seeds(seed=4)
    near = _noisy_rival(good, 0.0)  # within noise of `b`
    rows = []
    for method, values, measured in (("a", near, 2.01), ("b", good, 2.00)):
        for s in range(3):
            e = ModelEntry(f"{method} {s}", f"run-{method}-{s}", f"fit-{method}-{s}",
                           {"rmse/render": values[s]}, {"time/train_s": measured * 60})  # fmt: skip
            e.seed, e.method, e.train_budget = s, method, ("minutes", 2.0)
            rows.append(e)
    front = stats.training_front(Report("parent", "quick", "made up", "-", "-", rows))
    assert front["front"] == ["a @ 2 min", "b @ 2 min"] and front["dominated"] == {}
    assert {p[0] for p in front["points"].values()} == {2.0}
    worse = {s: v + 0.02 for s, v in good.items()}  # beyond noise: the same cost does not save it
    rows = [e for e in rows if e.method == "b"]
    for s in range(3):
        e = ModelEntry(f"c {s}", f"run-c-{s}", f"fit-c-{s}", {"rmse/render": worse[s]}, {"time/train_s": 119.0})
        e.seed, e.method, e.train_budget = s, "c", ("minutes", 2.0)
        rows.append(e)
    front = stats.training_front(Report("parent", "quick", "made up", "-", "-", rows))
    assert front["front"] == ["b @ 2 min"] and front["dominated"] == {"c @ 2 min": "b @ 2 min"}


def _noisy_rival(good: dict[int, np.ndarray], shift: float) -> dict[int, np.ndarray]:
    return {s: v + shift + 0.004 * np.random.default_rng(100 + s).standard_normal(v.size) for s, v in good.items()}


def test_verdicts_across_seeds_join_the_holm_family_and_say_when_it_overturns_them():
    from svbrdf_bench.report.verdicts import family

    good = _seeds(seed=4)
    said = {}
    for shift in (0.001, 0.0019):  # a verdict with p about 0.02, and one far beyond noise
        report = _report([("a", s, 10, good) for s in range(3)] + [("b", s, 10, _noisy_rival(good, shift))
                                                                   for s in range(3)])  # fmt: skip
        fam = family(report)
        v = fam.get("a @ 10 steps", "b @ 10 steps", "render")
        assert v is not None and v.kind == "across seeds" and v.verdict == "beats" and v.p_value < 0.05
        assert fam.count > len(stats.stated(report))  # the rows' own verdicts are in the family too
        words = "\n".join(section.section_lines(report))
        said[shift] = (v.survives, f"but not after Holm over {fam.count} comparisons" in words)
    assert said == {0.001: (False, True), 0.0019: (True, False)}


def test_what_accuracy_costs_pairs_a_checkpoint_only_with_its_seed_and_budget():
    good, bad = _seeds(seed=4), _seeds(seed=4, shift=0.01)
    report = _report([(m, s, b, v) for m, v in (("a", good), ("b", bad)) for s in range(3) for b in (10, 40)])
    pairs = {(c["model"], c["versus"]) for c in report.costs()}
    assert len(pairs) == 3 * 2  # a against b, per seed and budget; nothing across them
    for model, versus in pairs:
        assert model.split(" ", 1)[1] == versus.split(" ", 1)[1]  # "seed S @ B steps" alike
    one_each = _report([("a", 0, 10, good), ("b", 1, 40, bad)])  # one row a model: still paired
    assert {(c["model"], c["versus"]) for c in one_each.costs()} == {("a seed 0 @ 10 steps", "b seed 1 @ 40 steps")}


def test_one_seed_and_one_budget_per_model_has_no_section():
    report = _report([("a", 0, 10, _seeds(seed=5)), ("b", 0, 10, _seeds(seed=6))])
    assert not stats.shown(report) and section.seeds_table(report) is None
    assert section.section_json(report) is None and section.training_time_series(report) == {}
    one_seed = _report([("a", 0, 10, _seeds(seed=5)), ("a", 0, 40, _seeds(seed=5))])
    assert stats.shown(one_seed)
    assert any("One seed per model: these verdicts compare checkpoints" in line
               for line in section.section_lines(one_seed))  # fmt: skip


@pytest.mark.slow  # two tiny benchmarks (about 100 s on 2 cores)
def test_a_benchmark_stopped_in_the_middle_resumes_its_fits_and_keeps_them_only_until_it_ends(
    tmp_path, monkeypatch
):
    import subprocess

    from svbrdf_bench import children

    out, calls, real_run = tmp_path / "report", [], subprocess.run

    def fits_counted(stop_at: int | None):
        def run(cmd, *args, **kwargs):  # subprocess.run is patched for every caller: count the fits
            calls.extend([cmd] if "svbrdf_train" in cmd else [])
            if len(calls) == stop_at:  # Ctrl-C while this fit trains
                raise KeyboardInterrupt
            return real_run(cmd, *args, **kwargs)

        return run

    monkeypatch.setattr(children.subprocess, "run", fits_counted(stop_at=2))
    args = ["run", "--models", "ours", "--seeds", "2", "--steps", "1", *TINY, "-o", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 130  # stopped as Ctrl-C stops it
    assert "run the same command again to resume them" in result.stderr
    first = children.fits_folder(out) / "ours-seed-0"
    run_id = json.loads((first / "last.json").read_text())["run_id"]

    calls.clear()
    monkeypatch.setattr(children.subprocess, "run", fits_counted(stop_at=None))
    result = _invoke(*args)
    assert result.exit_code == 0, result.output
    assert "--resume" in calls[0] and "--force" not in calls[0]  # the first seed goes on in its run
    assert "--force" in calls[1] and "--resume" not in calls[1]  # the second starts again
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    rows = {c.info.run_id: c.data.tags["svbrdf.model"] for c in _children(parent) if "svbrdf.model" in c.data.tags}
    assert rows[run_id] == "ours seed 0" and len(rows) == 2  # the resumed fit is the new benchmark's row
    assert not children.fits_folder(out).exists()  # every fit is in MLflow: nothing left beside the report


# -- the rows of one fit, and reused seeds ------------------------------------------------------


def test_a_budget_the_fit_never_reached_is_missed_with_why(tmp_path):
    from svbrdf_bench.children import Fit, fit_rows
    from svbrdf_bench.seeding import TrainBudget

    client = _client()
    experiment = client.create_experiment("tests-fit-rows")
    fit = client.create_run(experiment, tags={"recipe": "ours"}).info.run_id
    parent = client.create_run(experiment).info
    (tmp_path / "snapshots").mkdir()
    (tmp_path / "snapshots" / "steps-1.pt").write_bytes(b"")
    (tmp_path / "last.json").write_text(json.dumps({"step": 1, "train_seconds": 30.0}))
    rows, missed = fit_rows(client, parent, Fit("ours", 2, fit, 5.0, tmp_path, seeds_shown=True),
                            TrainBudget("steps", (1.0, 2.0)))  # fmt: skip
    assert [r.label for r in rows] == ["ours seed 2 @ 1 step"] and rows[0].snapshot == "steps-1.pt"
    assert rows[0].local == tmp_path / "snapshots" / "steps-1.pt" and rows[0].fit_run == fit
    assert missed == [{"model": "ours", "seed": 2, "budget": "2 steps",
                       "why": "the fit ended before it, at step 1 after 0.50 min of training"}]  # fmt: skip
    child = client.get_run(rows[0].run_id).data.tags
    assert child["svbrdf.train_run"] == fit and child["svbrdf.budget"] == "1 step" and child["svbrdf.seed"] == "2"


def test_a_recipe_name_resolves_to_its_last_finished_fit_of_each_seed():
    from mlflow.entities import Param

    from svbrdf_bench.children import resolve_reuse

    client = _client()
    experiment = client.create_experiment("tests-reuse-seeds")
    ids = {}
    for seed in (0, 1, 1):
        run = client.create_run(experiment, tags={"recipe": "seed-lookup"}).info.run_id
        client.log_batch(run, params=[Param("train.seed", str(seed)), Param("data.seed", str(seed))])
        client.set_terminated(run)
        ids[seed] = run  # the later fit of seed 1 wins
    assert resolve_reuse(["seed-lookup"], seeds=2) == [("seed-lookup", ids[0]), ("seed-lookup", ids[1])]
    with pytest.raises(BenchError, match="finished fits of seeds 0, 1 only, of the 3"):
        resolve_reuse(["seed-lookup"], seeds=3)
    assert len(resolve_reuse(["seed-lookup"], seeds=3, trainable=["seed-lookup"])) == 2  # seed 2 is trained


# -- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--seeds", "0"], ["--seeds 0", "e.g. --seeds 3"]),
        (["--seeds", "x"], ["--seeds x"]),
        (["--minutes", "2,x"], ["--minutes 2,x", "'x' is not a number"]),
        (["--minutes", "8,2"], ["increasing"]),
        (["--minutes", "2,8", "--steps", "500"], ["--minutes 2,8 and --steps 500 both given"]),
        (["--steps", "1.5"], ["whole numbers of steps"]),
        (["--seeds", "2", "--set", "train.seed=3"], ["--set train.seed=3", "--seeds 2 sets it"]),
        (["--steps", "5,10", "--set", "train.max_steps=3"], ["--set train.max_steps=3", "--steps sets it"]),
    ],
)
def test_bad_seeds_and_budgets_are_one_line_errors(args, needles, tmp_path):
    result = _invoke("run", "--models", "ours", *args, "-o", tmp_path / "r")
    assert result.exit_code == 2, result.output
    err = "\n".join(line for line in result.stderr.splitlines() if " INFO mlflow." not in line)
    assert err.startswith("svbrdf-bench: error: ") and err.strip().count("\n") == 0, err
    for needle in needles:
        assert needle in err


def test_the_help_teaches_seeds_and_budgets_with_examples():
    text = _invoke("run", "--help").output
    for needle in ("--seeds 3", "--minutes 2,8,32", "--steps 500,2000", "--from-runs ours --seeds 3",
                   "accuracy_vs_training_time.png"):  # fmt: skip
        assert needle in text
