"""``svbrdf-bench render``: the renderer's accuracy-versus-time table."""

from __future__ import annotations

import csv
import json
import math
import re

import pytest
from click.testing import CliRunner

from svbrdf_bench.cli import cli
from svbrdf_bench.errors import BenchError
from svbrdf_bench.render_rows import Row, format_table, metric_key, to_records
from svbrdf_bench.render_table import bench_materials, effect_variants, measure
from svbrdf_render import DES18_EFFECTS

TOGGLES = [
    "-diffuse",
    "-specular",
    "-fresnel",
    "-masking",
    "-cosine",
    "-falloff",
    "+vignetting",
    "+exposure",
    "+noise",
    "+clip",
    "+tone",
    "+gamma",
]


@pytest.fixture(scope="module")
def quick_rows() -> list[Row]:
    return measure(size=16, materials=4, repeats=1, backends=("eager",))


def _row(rows, dtype, backend, effects) -> Row:
    found = [r for r in rows if (r.dtype, r.backend, r.effects) == (dtype, backend, effects)]
    assert len(found) == 1, (dtype, backend, effects)
    return found[0]


def test_effect_variants_toggle_each_effect_once():
    variants = dict(effect_variants())
    assert list(variants) == ["des18", *TOGGLES]
    assert variants["des18"] == DES18_EFFECTS
    assert variants["-specular"] == ("diffuse", "cosine", "falloff")  # the lobe goes whole
    assert variants["-fresnel"] == tuple(e for e in DES18_EFFECTS if e != "fresnel")
    assert variants["+noise"] == (*DES18_EFFECTS, "noise")


def test_bench_materials_are_valid_and_mixed():
    m = bench_materials(5, 16)
    assert m.shape == (5, 16, 16)
    assert m.normal.dtype.is_floating_point
    # three built-in examples, then seeded random maps
    assert not bench_materials(5, 16, seed=1).diffuse[3:].equal(m.diffuse[3:])
    assert bench_materials(5, 16, seed=1).diffuse[:3].equal(m.diffuse[:3])


def test_quick_measure_has_every_row(quick_rows):
    keys = [(r.dtype, r.backend, r.effects) for r in quick_rows]
    assert keys == [
        ("float64", "eager", "des18"),
        ("float32", "eager", "des18"),
        ("bfloat16", "eager", "des18"),
        *(("float32", "eager", t) for t in TOGGLES),
    ]
    for r in quick_rows:
        assert 0 < r.forward_ms < 60_000 and 0 < r.forward_backward_ms < 60_000, r
        assert r.first_call_s > 0
        assert len(r.forward_samples) == len(r.forward_backward_samples) == 1


def test_errors_against_the_float64_reference(quick_rows):
    f64 = _row(quick_rows, "float64", "eager", "des18")
    f32 = _row(quick_rows, "float32", "eager", "des18")
    bf16 = _row(quick_rows, "bfloat16", "eager", "des18")
    # eager float64 is the reference's own computation: exactly equal
    assert f64.max_abs_error == 0 and f64.max_rel_error == 0 and f64.grad_error == 0
    # float32 rounding: a few ulps relative (measured ~4e-6), gradients likewise
    assert 0 < f32.max_rel_error < 1e-4
    assert 0 < f32.grad_error < 1e-4
    # bfloat16 inputs keep 8 bits of mantissa: far worse than float32 (measured ~5e-2)
    assert bf16.max_rel_error > 1e-3
    assert bf16.max_rel_error > 100 * f32.max_rel_error
    assert bf16.max_abs_error > 100 * f32.max_abs_error
    assert bf16.grad_error > 100 * f32.grad_error


def test_effect_rows_are_compared_with_their_own_reference(quick_rows):
    for t in TOGGLES:
        r = _row(quick_rows, "float32", "eager", t)
        assert 0 <= r.grad_error < 1e-3, r
        if t == "+noise":
            # float32 and float64 draw different noise from one seed: not comparable
            assert math.isnan(r.max_abs_error) and "noise" in r.note
        else:
            assert 0 <= r.max_rel_error < 1e-3, r
            assert r.note == ""


def test_measure_rejects_bad_arguments():
    with pytest.raises(BenchError, match="size"):
        measure(size=0)
    with pytest.raises(BenchError, match="backend"):
        measure(size=8, materials=1, backends=("fast",))
    with pytest.raises(BenchError, match="dtype"):
        measure(size=8, materials=1, dtypes=("float16x",))
    with pytest.raises(BenchError, match="toggle"):
        measure(size=8, materials=1, effects=["-nothing"])


def test_format_table_and_records(quick_rows):
    table = format_table(quick_rows)
    lines = table.splitlines()
    assert len(lines) == len(quick_rows) + 2
    assert lines[0].startswith("| dtype | backend | effects | fwd ms | fwd+bwd ms |")
    noise = next(ln for ln in lines if "+noise" in ln)
    assert "| - |" in noise  # not measured, not "nan"
    assert "nan" not in table
    records = to_records(quick_rows)
    assert len(records) == len(quick_rows)
    json.dumps(records, allow_nan=False)  # NaN became None
    assert records[0]["max_abs_error"] == 0.0


def test_metric_keys_are_valid_mlflow_names(quick_rows):
    keys = {metric_key(r, "fwd_ms") for r in quick_rows}
    assert "fwd_ms/float32/eager/des18" in keys
    assert "fwd_ms/float32/eager/no-fresnel" in keys
    assert "fwd_ms/float32/eager/with-noise" in keys
    assert len(keys) == len(quick_rows)
    assert all(re.fullmatch(r"[/\w.\- ]+", k) for k in keys)


# -- the command ------------------------------------------------------------------------------


def _invoke(*args: str):
    return CliRunner().invoke(cli, ["render", *args], catch_exceptions=False)


def test_cli_quick_prints_the_table_and_writes_three_files(tmp_path):
    out = tmp_path / "bench"
    result = _invoke("--quick", "--no-track", "--size", "16", "--out", str(out))
    assert result.exit_code == 0, result.output
    stdout = result.stdout
    assert "torch " in stdout and "threads" in stdout and "device cpu" in stdout
    assert "| dtype | backend | effects |" in stdout
    assert "| float32 | eager | +gamma |" in stdout
    assert "compiled" not in stdout  # --quick is eager only
    assert "warm-up" in result.stderr and "warm-up" not in stdout
    md = (out / "render.md").read_text()
    assert "| bfloat16 | eager | des18 |" in md
    assert "max |grad - ref grad|" in md  # the legend travels with the table
    with (out / "render.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 + len(TOGGLES)
    assert rows[0]["dtype"] == "float64" and float(rows[0]["max_abs_error"]) == 0
    data = json.loads((out / "render.json").read_text())
    assert data["meta"]["size"] == 16 and data["meta"]["materials"] == 2
    assert data["meta"]["backends"] == ["eager"]
    assert len(data["rows"]) == 3 + len(TOGGLES)


def test_cli_logs_one_mlflow_run_with_the_files(tmp_path):
    from mlflow import MlflowClient

    experiment = "bench-render-test"
    result = _invoke(
        "--quick", "--size", "8", "--effects", "none", "--out", str(tmp_path), "--experiment", experiment
    )
    assert result.exit_code == 0, result.output
    client = MlflowClient()
    exp = client.get_experiment_by_name(experiment)
    runs = client.search_runs([exp.experiment_id], "tags.kind = 'render'")
    assert len(runs) == 1
    run = runs[0]
    assert run.info.status == "FINISHED"
    assert run.data.tags["torch"] and run.data.tags["device"].startswith("cpu")
    assert run.data.params["size"] == "8" and run.data.params["materials"] == "2"
    assert run.data.params["repeats"] == "1"
    assert run.data.metrics["max_abs_err/float64/eager/des18"] == 0
    assert run.data.metrics["fwd_ms/float32/eager/des18"] > 0
    assert "fwd_bwd_ms/bfloat16/eager/des18" in run.data.metrics
    names = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert names == {"render.md", "render.csv", "render.json"}


@pytest.mark.parametrize("args", [["--size", "0"], ["--materials", "0"], ["--repeats", "0"]])
def test_cli_bad_argument_is_one_line_exit_2(tmp_path, args):
    result = _invoke("--no-track", "--out", str(tmp_path), *args)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("svbrdf-bench: error: --")
    assert not (tmp_path / "render.md").exists()


def test_cli_help_explains_columns_with_examples():
    result = _invoke("--help")
    assert result.exit_code == 0
    for word in (
        "Examples:",
        "svbrdf-bench render --quick",
        "fwd+bwd ms",
        "max rel err",
        "grad err",
        "first call s",
        "float64",
        "bfloat16",
        "render.csv",
        "--no-track",
    ):
        assert word in result.output, word


@pytest.mark.slow
def test_compiled_rows_match_the_reference():
    """The compiled backend, float32 and float64 (compiles twice: tens of seconds)."""
    rows = measure(
        size=16,
        materials=2,
        repeats=1,
        backends=("compiled",),
        dtypes=("float64", "float32"),
        effects=["+exposure"],
    )
    assert [(r.dtype, r.effects) for r in rows] == [
        ("float64", "des18"),
        ("float32", "des18"),
        ("float32", "+exposure"),
    ]
    for r in rows:
        assert r.backend == "compiled" and r.note == "", r
        assert r.forward_backward_ms > 0
    f64, f32 = rows[0], rows[1]
    assert f64.max_rel_error < 1e-9 and f64.grad_error < 1e-9  # reordered float64 sums
    assert f32.max_rel_error < 1e-4 and f32.grad_error < 1e-4


@pytest.mark.filterwarnings("ignore:torch.compile failed")  # the fake warns on every call
def test_a_failing_or_falling_back_row_is_noted_not_fatal(monkeypatch):
    """A backend that raises keeps its row, NaN and why; a compile fallback is noted."""
    import warnings

    import torch

    import svbrdf_bench.render_table as rt

    real = rt.render

    def fake(maps, scene, backend="eager"):
        if backend == "compiled":
            if maps.dtype == torch.float64:
                raise RuntimeError("no kernel for double\nmore detail")
            warnings.warn("torch.compile failed (no C++ compiler); using the eager backend", stacklevel=2)
        return real(maps, scene)

    monkeypatch.setattr(rt, "render", fake)
    rows = measure(size=8, materials=1, repeats=1, dtypes=("float64", "float32"), effects="none")
    f64c = _row(rows, "float64", "compiled", "des18")
    assert f64c.note == "failed: RuntimeError: no kernel for double"
    assert math.isnan(f64c.forward_ms) and math.isnan(f64c.max_abs_error)
    f32c = _row(rows, "float32", "compiled", "des18")
    assert f32c.note.startswith("torch.compile failed") and f32c.note.endswith("(timed eager)")
    assert f32c.forward_ms > 0 and f32c.max_rel_error < 1e-4
    assert _row(rows, "float32", "eager", "des18").note == ""
    assert "| - |" in format_table(rows)
