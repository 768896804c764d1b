"""Timings with their spread and the load they were measured under (svbrdf_bench.timing), the
report's warning when the load makes them unreliable, and the noise-aware Pareto front.

No test asserts how fast anything is: only lower bounds a sleep guarantees, counts, and the
summaries of times the test knows.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from svbrdf_bench.errors import BenchError
from svbrdf_bench.plots import dominated_by, pareto, pareto_front
from svbrdf_bench.render_rows import timing_warning, to_records
from svbrdf_bench.render_table import measure
from svbrdf_bench.report import ModelEntry, Report, markdown, table_lines, terminal
from svbrdf_bench.report import words as report_words
from svbrdf_bench.report.tables import time_table
from svbrdf_bench.scoring import _latency, _step_spread
from svbrdf_bench.timing import (
    CPU_WAIT_LIMIT,
    LATENCY_METRIC,
    Load,
    summarize,
    time_call,
)

# -- the timing function --------------------------------------------------------------------------


def test_summarize_gives_the_median_and_interquartile_range_of_known_times():
    t = summarize([8.0, 1.0, 7.0, 2.0, 6.0, 3.0, 5.0, 4.0])
    # Linear interpolation on 1..8: the 25th percentile sits at rank 1.75 (2.75), the 75th at 5.25 (6.25).
    assert t.median_ms == pytest.approx(4.5) and t.iqr_ms == pytest.approx(3.5) and t.runs == 8
    m = t.metrics("time/latency")
    assert m == {"time/latency_ms": 4.5, "time/latency_iqr_ms": pytest.approx(3.5), "time/latency_runs": 8.0}
    assert summarize([3.0]).iqr_ms == 0.0
    with pytest.raises(BenchError, match="at least one finite time"):
        summarize([])
    with pytest.raises(BenchError, match="at least one finite time"):
        summarize([1.0, float("nan")])


def test_time_call_times_each_run_after_the_warm_up():
    calls = []

    def work():  # alternately 1 ms and 4 ms of sleep: a sleep never ends early
        time.sleep(0.001 if len(calls) % 2 else 0.004)
        calls.append(1)

    t = time_call(work, 10, warmup=3)
    assert len(calls) == 13 and t.runs == 10
    samples = np.asarray(t.samples_ms)
    assert samples.min() >= 1.0  # one sample per call, in ms (not an average over a block)
    assert (samples >= 4.0).sum() >= 5  # the five long calls stay long
    assert t.median_ms >= 2.5  # between the 5th and 6th sorted times: (>= 1 + >= 4) / 2
    assert t.median_ms == pytest.approx(float(np.median(samples)))
    assert t.iqr_ms == pytest.approx(float(np.percentile(samples, 75) - np.percentile(samples, 25)))
    assert isinstance(t.load, Load) and t.load.cpus >= 1 and t.load.threads == torch.get_num_threads()
    metrics = t.metrics(LATENCY_METRIC)
    assert metrics["time/latency_ms"] == t.median_ms and metrics["time/latency_cpus"] == t.load.cpus
    with pytest.raises(BenchError, match="runs must be >= 1"):
        time_call(work, 0)


def test_runner_latency_logs_the_median_spread_and_load():
    net = torch.nn.Conv2d(3, 4, 3, padding=1).eval()
    figures = _latency(net, torch.device("cpu"), 5)
    assert figures["time/latency_runs"] == 5
    assert figures["time/latency_ms"] > 0 and figures["time/latency_iqr_ms"] >= 0
    load = Load.from_metrics(figures, LATENCY_METRIC)
    assert load is not None and load.cpus >= 1


def test_step_spread_reads_the_fit_logging_windows():
    class Point:
        def __init__(self, step, value):
            self.step, self.value = step, value

    class Client:
        def __init__(self, rates):
            self.rates = rates

        def get_metric_history(self, run_id, key):
            assert key == "train/samples_per_s"
            return [Point(10 * (i + 1), r) for i, r in reversed(list(enumerate(self.rates)))]

    # batch 8: the first window (warm-up) is left out; then 160, 200, 100, 400 ms per step.
    spread = _step_spread(Client([1.0, 50.0, 40.0, 80.0, 20.0]), "run", 8)
    assert spread["time/train_ms_per_step_median"] == pytest.approx(180.0)
    assert spread["time/train_ms_per_step_iqr"] == pytest.approx(250.0 - 145.0)
    assert _step_spread(Client([1.0, 50.0, 40.0]), "run", 8) == {}  # too few windows for quartiles


def test_render_table_rows_carry_the_spread_and_one_load_reading():
    rows = measure(size=8, materials=1, repeats=4, backends=("eager",), dtypes=("float32", "float64"),
                   effects="none")  # fmt: skip
    for r in rows:
        f = np.asarray(r.forward_samples)
        assert r.forward_iqr_ms == pytest.approx(float(np.percentile(f, 75) - np.percentile(f, 25)))
        assert r.forward_ms == pytest.approx(float(np.median(f)))
        assert r.forward_backward_iqr_ms >= 0
    assert rows[0].load is not None and all(r.load is rows[0].load for r in rows)
    record = to_records(rows)[0]
    assert {"forward_iqr_ms", "load_cpu_wait", "load_unreliable"} <= set(record)
    assert "load" not in record
    busy = Load(wall_s=1.0, cpus=2, threads=1, cpu_wait=0.5, other_cpus=1.5, load_average=4.0)
    for r in rows:
        r.load = busy
    assert "unreliable" in timing_warning(rows) and "10%" in timing_warning(rows)
    for r in rows:
        r.load = Load(wall_s=1.0, cpus=2, threads=1, cpu_wait=0.01)
    assert timing_warning(rows) is None


# -- the load -----------------------------------------------------------------------------------


def test_load_verdict_and_its_metrics():
    assert Load(1.0, 2, cpu_wait=0.3).unreliable is True
    assert Load(1.0, 2, cpu_wait=0.02, load_average=9.0).unreliable is False  # the direct reading decides
    assert Load(1.0, 2, load_average=3.0).unreliable is True  # no /proc: more runnable tasks than CPUs
    assert Load(1.0, 2, load_average=1.5).unreliable is False
    assert Load(1.0, 2).unreliable is None and "not measured" in Load(1.0, 2).words()
    load = Load(2.0, 4, threads=2, cpu_wait=0.25, other_cpus=1.5, load_average=5.0)
    back = Load.from_metrics(load.metrics("time/latency"), "time/latency")
    assert (back.cpus, back.threads, back.cpu_wait, back.other_cpus, back.load_average) == (4, 2, 0.25, 1.5, 5.0)
    assert "25% of the time" in load.words() and "1.5 of 4 CPUs" in load.words()
    assert Load.from_metrics({"time/latency_ms": 3.0}, "time/latency") is None  # an older run


def _burner(cpu: int) -> subprocess.Popen:
    code = f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True:\n    pass\n"
    return subprocess.Popen([sys.executable, "-c", code])


@pytest.mark.slow
@pytest.mark.skipif(
    not (hasattr(os, "sched_setaffinity") and Path("/proc/self/task").is_dir()), reason="Linux only"
)
def test_load_reads_high_while_burners_share_the_cpu_and_the_report_says_so():
    """Two burners on the CPU the timing runs on (pinned, so that they compete on any machine)."""
    cpu = min(os.sched_getaffinity(0))
    before = os.sched_getaffinity(0)
    burners = [_burner(cpu), _burner(cpu)]
    try:
        time.sleep(0.5)  # the burners are running
        os.sched_setaffinity(0, {cpu})

        def spin():
            end = time.perf_counter() + 0.005
            while time.perf_counter() < end:
                pass

        t = time_call(spin, 40, warmup=1, threads=1)
    finally:
        os.sched_setaffinity(0, before)
        for b in burners:
            b.kill()
            b.wait()
    assert t.load.cpu_wait is not None and t.load.cpu_wait > CPU_WAIT_LIMIT, t.load
    assert t.load.unreliable
    report = _report({"fast": 0.0, "slow": 0.0}, latency={"fast": t.metrics(LATENCY_METRIC)})
    assert "TIMINGS UNRELIABLE" in terminal(report) and "fast" in report_words.timing_warning(report)


# -- the report ---------------------------------------------------------------------------------

N = 40
COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")


def _report(shift: dict[str, float], *, latency: dict[str, dict] | None = None, noise=0.002) -> Report:
    """Rows whose render RMSE is ``base + shift[name]`` plus independent noise of ``noise``; latency
    figures per row (default: 10 ms per row in order, IQR 0.5, measured on an idle machine)."""
    rng = np.random.default_rng(1)
    base = 0.1 + 0.02 * rng.random(N)
    models = []
    for i, (name, d) in enumerate(shift.items()):
        rmse = {f"rmse/{c}": base + d + noise * rng.standard_normal(N) for c in COLUMNS}
        figures = {"model/params": 1e5}
        figures |= (latency or {}).get(name) or {
            "time/latency_ms": 10.0 * (i + 1), "time/latency_iqr_ms": 0.5, "time/latency_runs": 20.0,
            **Load(1.0, 2, threads=1, cpu_wait=0.01, other_cpus=0.1, load_average=0.3).metrics(LATENCY_METRIC),
        }  # fmt: skip
        models.append(ModelEntry(name, f"run-{name}", f"run-{name}", rmse, figures))
    return Report("parent", "quick", "32 procedural materials", "LPIPS skipped", "2.0 min", models, baselines="-")


def test_report_shows_median_and_iqr_and_no_warning_on_an_idle_machine():
    report = _report({"no-attn": 0.0, "ours": -0.02})
    assert report_words.timing_warning(report) is None
    table = "\n".join(table_lines(time_table(report), True))
    assert "| 10.0 [0.5] |" in table and "| 20.0 [0.5] |" in table
    notes = report_words.timing_notes(report)
    assert "median [interquartile range] of 20 timed runs" in notes[0]
    assert "under the 10% limit" in notes[1]
    assert "UNRELIABLE" not in markdown(report, {})
    records = {r["model"]: r for r in report.records()}
    assert records["ours"]["time_latency_iqr_ms"] == 0.5 and records["ours"]["time_latency_unreliable"] is False


def test_report_warns_in_words_when_the_load_makes_timings_unreliable():
    busy = {
        "time/latency_ms": 1343.7, "time/latency_iqr_ms": 400.0, "time/latency_runs": 20.0,
        **Load(30.0, 2, threads=2, cpu_wait=0.45, other_cpus=1.6, load_average=3.9).metrics(LATENCY_METRIC),
    }  # fmt: skip
    report = _report({"no-attn": 0.0, "ours": -0.02}, latency={"ours": busy})
    warning = report_words.timing_warning(report)
    assert warning.startswith("TIMINGS UNRELIABLE") and "latency of ours was measured" in warning
    assert "45% of the time" in warning and "more than 10% of the time" in warning and "11%" in warning
    md = markdown(report, {})
    assert f"**{warning}**" in md.splitlines()
    assert warning in terminal(report).splitlines()
    assert "| 1343.7 [400.0] |" in md
    assert "wide spread (IQR over 10% of the median latency): ours (30%)" in report_words.timing_notes(report)
    assert "measured on a busy machine" in md  # the front says so too


def test_report_of_an_older_run_without_spread_or_load():
    old = {"time/latency_ms": 19.3}
    report = _report({"a": 0.0, "b": -0.02}, latency={"a": old, "b": old})
    assert report_words.timing_warning(report) is None
    assert "| 19.3 |" in "\n".join(table_lines(time_table(report), True))
    assert any("was not recorded" in n for n in report_words.timing_notes(report))


# -- the noise-aware Pareto front ----------------------------------------------------------------


def test_a_slower_point_within_noise_of_a_faster_one_is_dominated():
    points = {"no-attn": (15.0, 0.050, 0.048, 0.052), "ours": (19.3, 0.049, 0.047, 0.051)}
    assert pareto_front(points) == ["no-attn", "ours"]  # by the means alone, ours is on the front
    assert pareto_front(points, within_noise=[("ours", "no-attn")]) == ["no-attn"]
    assert dominated_by(points, within_noise=[("ours", "no-attn")]) == {"no-attn": None, "ours": "no-attn"}
    # As fast and within noise: neither dominates.
    same = {"a": (10.0, 0.05, 0.04, 0.06), "b": (10.0, 0.04, 0.03, 0.05)}
    assert pareto_front(same, within_noise=[("a", "b")]) == ["b", "a"]
    # Noise is not transitive: C is better than A beyond noise, but B is faster and within noise of C.
    chain = {"A": (1.0, 0.30, 0, 1), "B": (2.0, 0.25, 0, 1), "C": (3.0, 0.20, 0, 1)}
    assert dominated_by(chain, within_noise=[("A", "B"), ("B", "C")]) == {"A": None, "B": "A", "C": "B"}
    with pytest.raises(BenchError, match="pairs of two model names"):
        pareto_front(points, within_noise=[("ours",)])


def test_report_front_uses_the_paired_bootstrap(tmp_path):
    noise = _report({"no-attn": 0.0, "ours": -0.0003})  # ours is slower, its gain within noise
    front = noise.latency_front()
    assert front["front"] == ["no-attn"] and front["dominated"] == {"ours": "no-attn"}
    assert front["within_noise"] == [("no-attn", "ours")]
    words = report_words.front_lines(noise)[0]
    assert "ours (no-attn is faster and within noise of it in render RMSE)" in words
    better = _report({"no-attn": 0.0, "ours": -0.02})  # ours is slower but better beyond noise
    front = better.latency_front()
    assert front["front"] == ["no-attn", "ours"] and front["dominated"] == {}
    assert pareto(front["points"], tmp_path / "p.png", within_noise=noise.latency_front()["within_noise"]).is_file()
    assert math.isclose(front["points"]["ours"][0], 20.0)
