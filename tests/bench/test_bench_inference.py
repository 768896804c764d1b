"""Inference cost (svbrdf_bench.inference): FLOPs against a hand count, the latency grid and its
refusals, the figures of one row, the report's table, and a benchmark that records them all.

No test asserts how fast anything is: only that a figure is there, positive, and counts what it says.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from test_bench_models import tiny_model
from test_bench_run import TINY, _invoke, _section

import svbrdf_models as sm
from svbrdf_bench.errors import BenchError
from svbrdf_bench.inference import (
    BASE_POINT,
    FLOPS_METRIC,
    GridPoint,
    forward_flops,
    grid_points,
    inference_cost,
    parse_latency_grid,
)
from svbrdf_bench.report import ModelEntry, Report, terminal
from svbrdf_bench.report.inference import inference_table
from svbrdf_bench.timing import CPU_WAIT_LIMIT

CPU = torch.device("cpu")

# -- FLOPs ------------------------------------------------------------------------------------------


def test_the_flops_of_one_convolution_are_the_hand_count():
    """2 FLOPs (a multiply and an add) per weight and output pixel: 2 * Cin * Cout * k * k * H * W."""
    conv = torch.nn.Conv2d(3, 5, 3, padding=1, bias=False)
    assert forward_flops(conv, 64, CPU) == 2 * 3 * 5 * 3 * 3 * 64 * 64
    # A transposed convolution spreads each input pixel over k x k outputs: 2 * Cin * Cout * k * k * Hin * Win.
    deconv = torch.nn.ConvTranspose2d(3, 4, 4, stride=2, padding=1, bias=False)
    assert forward_flops(deconv, 32, CPU) == 2 * 3 * 4 * 4 * 4 * 32 * 32


def test_a_generator_s_flops_grow_with_the_pixel_count():
    """What the docs say: x4 per doubled side, the global track's fully connected layers apart."""
    g = sm.create_generator("ours", {"preset": "tiny"}).eval()
    small, large = forward_flops(g, 128, CPU), forward_flops(g, 256, CPU)
    assert 3.99 < large / small <= 4.0


# -- the latency grid -------------------------------------------------------------------------------


def test_the_latency_grid_parses_sorted_with_256x1_always_in():
    grid = parse_latency_grid(" 512x1,256X8 ")
    assert grid == (GridPoint(256, 1), GridPoint(256, 8), GridPoint(512, 1))
    assert parse_latency_grid("256x1") == (BASE_POINT,)
    assert [p.name for p in parse_latency_grid("1024x8,16x1")] == ["16x1", "256x1", "1024x8"]
    # 256x1 is the benchmark's latency itself; the others are named by size and batch.
    assert BASE_POINT.metric == "time/latency" and GridPoint(512, 8).metric == "time/latency_512px_b8"
    keys = {"time/latency_ms", "time/latency_512px_b8_ms", "time/latency_512px_b8_iqr_ms", "model/params"}
    assert grid_points(keys) == [BASE_POINT, GridPoint(512, 8)]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("", "is empty"),
        ("512", "'512' is not SIZExBATCH"),
        ("512x", "is not SIZExBATCH"),
        ("256x8x2", "is not SIZExBATCH"),
        ("256*8", "is not SIZExBATCH"),
        ("256x1,,512x1", "'' is not SIZExBATCH"),
        ("512x0", "'512x0' is out of range"),
        ("8x1", "out of range"),
        ("9000x1", "out of range"),
        ("256x1000", "out of range"),
        ("512x1,512x1", "'512x1' is given twice"),
    ],
)
def test_a_bad_latency_grid_is_refused_saying_how_to_write_one(text, needle):
    with pytest.raises(BenchError) as e:
        parse_latency_grid(text)
    assert needle in str(e.value) and "--latency-grid" in str(e.value) and "\n" not in str(e.value)


def test_the_command_refuses_a_bad_grid_in_one_line_and_takes_a_good_one():
    from svbrdf_bench.cli import cli
    from svbrdf_bench.commands.run import _bench_options

    result = _invoke("run", "--models", "ours", "--latency-grid", "512")
    assert result.exit_code == 2
    err = [line for line in result.stderr.splitlines() if " INFO mlflow." not in line and line.strip()]
    assert len(err) == 1 and err[0].startswith("svbrdf-bench: error: --latency-grid '512'"), err

    def points(*args):
        flags = cli.commands["run"].make_context("run", ["--models", "ours", *args]).params
        return [p.name for p in _bench_options(flags).latency_points()]

    assert points() == ["256x1", "256x8", "512x1"]  # the quick preset's
    assert points("--preset", "standard") == ["256x1", "256x8", "512x1", "512x8", "1024x1", "1024x8"]
    assert points("--latency-grid", "1024x8") == ["256x1", "1024x8"]
    assert "--latency-grid" in _invoke("run", "--help").output


# -- one row's figures ------------------------------------------------------------------------------


def test_a_row_gets_its_flops_and_a_latency_per_point_it_can_take():
    g = sm.create_generator("ours", {"preset": "tiny"}).eval()  # a U-Net of depth 4: multiples of 16 px
    said = []
    threads = torch.get_num_threads()
    grid = parse_latency_grid("256x1,32x2,40x1")
    figures = inference_cost(g, CPU, grid, 3, "tiny", said.append)
    assert torch.get_num_threads() == threads  # timed on one thread, the count restored
    assert figures[FLOPS_METRIC] == forward_flops(g, 256, CPU) > 0
    assert figures["time/latency_32px_b2_ms"] > 0 and figures["time/latency_32px_b2_runs"] == 3
    assert figures["time/latency_32px_b2_iqr_ms"] >= 0
    # 256x1 is the row's time/latency_ms, timed apart; 40 px does not go through the U-Net.
    assert not any(k.startswith(("time/latency_ms", "time/latency_40px")) for k in figures)
    assert any("40x1" in line and "tiny" in line for line in said)
    assert not any(k.startswith("memory/") for k in figures)  # CUDA only


# -- the report -------------------------------------------------------------------------------------


def _entry(name: str, cpu_wait: float) -> ModelEntry:
    figures = {"model/params": 2.5e6, FLOPS_METRIC: 1.5e9, "time/latency_ms": 19.3, "time/latency_iqr_ms": 0.8,
               "time/latency_runs": 50.0, "time/latency_512px_b1_ms": 80.25, "time/latency_512px_b1_iqr_ms": 2.0,
               "time/latency_512px_b1_runs": 5.0, "time/latency_512px_b1_cpu_wait": cpu_wait}  # fmt: skip
    per_sample = {f"rmse/{c}": np.array([0.1, 0.2, 0.15]) for c in ("normal", "diffuse", "roughness", "specular", "render")}
    return ModelEntry(name, f"run-{name}", f"run-{name}", per_sample, figures)


def test_the_report_s_inference_table_sets_latency_beside_parameters_and_flops():
    report = Report("parent", "quick", "32 procedural materials", "LPIPS skipped", "2.0 min",
                    [_entry("ours", 0.01), _entry("no-attn", 2 * CPU_WAIT_LIMIT)], baselines="-")  # fmt: skip
    table = inference_table(report)
    assert table.head == ["model", "params (M)", "GFLOP/image 256px", "256px b1 ms [IQR]", "512px b1 ms [IQR]"]
    assert table.rows[0] == ["ours", "2.50", "1.5", "19.3 [0.8]", "80.2 [2.0]"]
    assert table.rows[1][-1] == "80.2 [2.0]*"  # timed on a busy machine: marked, and said why
    assert any(line.startswith("* a timed thread waited") for line in table.after)
    assert any("x4 at 512 px, x16 at 1024 px" in line for line in table.after)
    assert "50 timed runs at 256x1, 5 at the others" in " ".join(table.after)
    assert "Inference cost" in terminal(report)
    on_gpu = _entry("ours", 0.0)
    on_gpu.figures["memory/inference_peak_cuda_mb_512px_b1"] = 850.4
    assert inference_table(Report("p", "quick", "t", "l", "2.0 min", [on_gpu])).rows[0][-1] == "80.2 [2.0] 850 MB"
    older = Report("p", "quick", "t", "l", "2.0 min", [ModelEntry("a", "r", "r", {}, {"time/latency_ms": 9.0})])
    assert inference_table(older) is None  # nothing beyond the time table's latency


# -- a benchmark ------------------------------------------------------------------------------------


def test_a_quick_benchmark_records_flops_and_the_latency_grid(tmp_path):
    """A model file scored as a reference row (nothing trained): every row of results.json and
    every child run in MLflow carries parameters, FLOPs and the quick preset's latency grid."""
    from mlflow import MlflowClient

    from conftest import des18_strips

    tiny_model(tmp_path / "fold0.pt")
    judge = des18_strips(tmp_path / "judge", count=2)
    out = tmp_path / "report"
    result = _invoke("run", "--from-models", tmp_path / "fold0.pt", "--test-data", judge, *TINY, "-o", out)
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    records = {r["model"]: r for r in results["models"]}
    assert len(records) == 3  # the model file, mean, photo
    tiny = sm.create_generator("ours", {"preset": "tiny"}).eval()
    for rec in records.values():
        assert rec["model_params"] >= 0 and rec["model_flops_per_image_256px"] >= 0
        for point in ("256px_b8", "512px_b1"):
            assert rec[f"time_latency_{point}_ms"] > 0 and rec[f"time_latency_{point}_runs"] == 5
    (ref,) = [r for r in records.values() if r["reference"]]
    assert ref["model_params"] == 139489 and ref["model_flops_per_image_256px"] == forward_flops(tiny, 256, CPU)
    client = MlflowClient()
    child = client.get_run(ref["run_id"]).data.metrics
    assert child["model/flops_per_image_256px"] == ref["model_flops_per_image_256px"]
    assert child["time/latency_512px_b1_ms"] == ref["time_latency_512px_b1_ms"]
    table = _section(result.stdout, "Inference cost")
    assert "512px b1 ms [IQR]" in table[1] and len(table) == 3 + 3
    assert not math.isnan(ref["time_latency_256px_b8_iqr_ms"])
