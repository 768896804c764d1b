"""``svbrdf-bench run --from-models`` / ``--models pretrained``: model files trained elsewhere
scored beside the benchmark's own models as reference rows, and the refusals that keep them
honest (test strips they trained on, another resolution, a file that is not there).

The model files are tiny (the smoke generator, random weights) with a hand-written provenance,
so their labels are known exactly; one is exported from a real smoke fit, to check that what
``svbrdf-train export`` records is what the benchmark reads.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from test_bench_run import TINY, _invoke, _section

import svbrdf_models as sm
from conftest import des18_strips, run_cli

COLUMNS = ("normal", "diffuse", "roughness", "specular", "render")
#: The label of the tiny model file below: its name, generator, resolution, steps, time, device.
LABEL = "fold0 (reference: ours, 32 px, 8.3k steps, 1.1 h CPU; not equal-budget)"


def tiny_model(path, *, resolution=32, files=(), steps=8300, seconds=3960.0, device="cpu",
               hardware="2 cores of Test CPU, torch 1 threads", seed=0):  # fmt: skip
    """A model file of the smoke generator (random weights) whose provenance says it trained
    ``steps`` steps for ``seconds`` on ``device``, on procedural materials and the Des18 strips
    ``files``; returns its SHA-256."""
    from svbrdf_models.modelfile.files import model_dict, save_model

    torch.manual_seed(seed)
    generator = sm.create_generator("ours", {"preset": "tiny"})
    sources = [{"source": "procedural", "weight": 0.5, "seed": 0}]
    if files:
        sources.append({"source": "des18", "weight": 0.5, "path": ["strips"], "files": list(files)})
    provenance = {
        "recipe": "ours-mix", "size": "cpu", "steps": steps, "samples": steps * 8,
        "train_seconds": seconds, "wall_seconds": 1.2 * seconds, "device": device, "hardware": hardware,
        "world_size": 1, "git_sha": "0" * 40, "data": {"sources": sources},
    }  # fmt: skip
    contents = model_dict(
        "ours", {"preset": "tiny"}, generator.state_dict(), resolution=resolution, provenance=provenance
    )
    return save_model(path, contents)


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


def _children(parent_id: str) -> dict:
    client = _client()
    runs = client.search_runs(
        [client.get_run(parent_id).info.experiment_id],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent_id}'",
    )
    return {r.data.tags["svbrdf.model"]: r for r in runs}


def _rows(table: list[str], labels: list[str]) -> list[str]:
    """The row labels of a terminal table, matched against the known (space-holding) labels."""
    return [next(label for label in labels if line.startswith(label + "  ")) for line in table[3:]]


def _trained(output: str) -> bool:
    """Whether the benchmark started a fit (it says ``[1/N] training RECIPE``)."""
    return "] training " in output


def _errors(result) -> list[str]:
    # MLflow logs its own INFO lines when a store is first created; the error itself is one line
    return [line for line in result.stderr.splitlines() if " INFO mlflow." not in line and line.strip()]


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """Six Des18 strips: the model file trained on the first four; ``judge`` holds the other two."""
    root = tmp_path_factory.mktemp("models")
    strips = des18_strips(root / "all", count=6)
    judge = root / "judge"
    judge.mkdir()
    for strip in sorted(strips.iterdir())[4:]:
        (judge / strip.name).write_bytes(strip.read_bytes())
    trained = [p.name for p in sorted(strips.iterdir())[:4]]
    sha = tiny_model(root / "fold0.pt", files=trained)
    return root, strips, judge, root / "fold0.pt", sha


@pytest.fixture(scope="module")
def bench(folders, tmp_path_factory):
    """``--models ours --from-models fold0.pt`` on the two strips fold0 never saw."""
    root, _, judge, model, _ = folders
    out = tmp_path_factory.mktemp("bench") / "report"
    result = _invoke(
        "run", "--models", "ours", "--from-models", model, "--test-data", judge, *TINY, "-o", out
    )
    assert result.exit_code == 0, result.output
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    return out, result, parent


ROWS = ["ours", LABEL, "mean (baseline)", "photo (baseline)"]


def test_a_reference_row_stands_beside_the_trained_model_with_its_budget(bench):
    out, result, _ = bench
    assert "training ours" in result.stderr  # the recipe still trains as usual
    assert "training fold0" not in result.stderr and f"evaluating {LABEL} on 2 test images" in result.stderr
    for title in ("RMSE", "SSIM", "Against the mean baseline"):
        table = _section(result.stdout, title)
        want = ROWS if title != "Against the mean baseline" else ROWS[:2]
        assert _rows(table, ROWS) == want, title
    records = {r["model"]: r for r in json.loads((out / "results.json").read_text())["models"]}
    assert list(records) == ["ours", LABEL, "mean", "photo"]
    ref = records[LABEL]
    assert ref["reference"] is True and ref["baseline"] is False and records["ours"]["reference"] is False
    for metric in ("rmse", "ssim"):
        for c in COLUMNS:
            assert ref[f"{metric}_{c}_low"] <= ref[f"{metric}_{c}"] <= ref[f"{metric}_{c}_high"]
    assert ref["time_latency_ms"] > 0 and ref["model_params"] == 139489
    assert ref["reference_steps"] == "8300" and ref["reference_train_seconds"] == "3960.0"
    assert ref["reference_summary"] == "ours, 32 px, 8.3k steps, 1.1 h CPU"
    against = [
        r for r in json.loads((out / "results.json").read_text())["against_mean"] if r["model"] == LABEL
    ]
    assert [r["column"] for r in against] == list(COLUMNS)


def test_the_reference_row_s_figures_are_its_model_s_on_the_test_images(bench, folders):
    """The per-image figures are those of the file's generator on the same resized strips."""
    from svbrdf_bench.metrics import evaluate
    from svbrdf_bench.report import build_report
    from svbrdf_bench.testset import test_set
    from svbrdf_render import SVBRDF

    _, _, parent = bench
    _, _, judge, model, _ = folders
    test = test_set(judge, 32, 0)
    photos = torch.stack([test[i]["input"] for i in range(len(test))])
    target = SVBRDF.unpack(torch.stack([test[i]["maps"] for i in range(len(test))]), validate=False)
    with torch.no_grad():
        expected = evaluate(sm.load_model(model).generator(photos), target)
    entries = {e.label: e for e in build_report(parent).models}  # as benchmarks/ scripts read them
    assert set(entries) == {"ours", LABEL, "mean", "photo"}
    for c in COLUMNS:
        assert entries[LABEL].per_sample[f"rmse/{c}"] == pytest.approx(expected[f"rmse/{c}"], rel=1e-5)
        assert len(entries["ours"].per_sample[f"rmse/{c}"]) == len(test)  # the same images for every row
    assert not np.allclose(
        entries[LABEL].per_sample["rmse/render"], entries["ours"].per_sample["rmse/render"]
    )


def test_budgets_and_costs_mark_the_reference_row(bench):
    out, result, _ = bench
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"svbrdf-bench: ours, {LABEL}, mean (baseline)")
    assert lines[0].endswith("min of training per model; reference rows: their own budgets, not equal)")
    assert any(line.startswith("reference rows are model files trained elsewhere") for line in lines[:8])
    time_table = _section(result.stdout, "Time and memory")
    ref = next(line.split() for line in time_table[3:] if line.startswith("fold0 (reference)  "))
    assert ref[2:5] == ["3960.0", "4752.0", "8300"]  # the file's training time, wall time and steps
    assert (
        "Rows marked (reference): training time and steps as their model files record them" in result.stdout
    )
    costs = _section(result.stdout, "What accuracy costs")
    assert costs[0] == "What accuracy costs (trained models; reference rows: not equal-budget)"
    assert costs[3].split("  ")[0] in ("fold0 (reference) vs ours", "ours vs fold0 (reference)")
    assert any("no comparison at equal training cost" in line for line in costs[4:])
    md = (out / "report.md").read_text()
    assert f"| {LABEL} |" in md and "| fold0 (reference) |" in md
    assert "reference rows: their own budgets, not equal" in md.split("## ")[0]
    assert json.loads((out / "results.json").read_text())["costs"][0]["reference"] is True


def test_the_reference_child_run_logs_the_file_s_hash_and_budget(bench, folders):
    _, _, parent = bench
    *_, model, sha = folders
    children = _children(parent)
    assert set(children) == {"ours", LABEL, "mean", "photo"}
    child = children[LABEL]
    tags, params = child.data.tags, child.data.params
    assert child.info.status == "FINISHED" and child.info.run_name == "fold0 (reference)"
    assert tags["svbrdf.reference"] == "fold0" and tags["svbrdf.model_sha256"] == sha
    assert tags["svbrdf.model_source"] == str(model) and "recipe" not in tags  # never taken for a fit
    assert params["model.sha256"] == sha and params["model.resolution"] == "32"
    assert params["budget.steps"] == "8300" and params["budget.train_seconds"] == "3960.0"
    assert params["budget.device"] == "cpu" and params["budget.hardware"].startswith("2 cores of Test CPU")
    assert params["budget.data"] == "procedural x0.5 (seed 0); des18 x0.5 (4 files)"
    m = child.data.metrics
    assert m["train/steps"] == 8300 and m["time/train_s"] == 3960 and m["time/latency_ms"] > 0
    assert _client().get_run(parent).data.params["reference_models"] == f"{model}@{sha[:12]}"


def test_the_report_rebuilds_the_reference_row_from_mlflow(bench, tmp_path):
    _, result, parent = bench
    again = _invoke("report", parent, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    assert again.stdout == result.stdout


def test_the_shipped_model_is_a_reference_row(tmp_path):
    """``--models pretrained`` trains nothing: the shipped model, then the baselines, on test
    images at its own resolution. What the model scores is not asserted (it gets replaced)."""
    from svbrdf_bench.presets import TEST_SEED

    shipped = sm.load_model("pretrained")
    out = tmp_path / "r"
    result = _invoke(
        "run", "--models", "pretrained", "--test-count", "3", "--experiment", "tests-bench", "-o", out
    )
    assert result.exit_code == 0, result.output
    assert not _trained(result.stderr)
    (label,) = [
        r["model"] for r in json.loads((out / "results.json").read_text())["models"] if r["reference"]
    ]
    name = shipped.source.split(":")[1]
    assert label.startswith(f"{name} (reference: {shipped.name}, {shipped.resolution} px, ")
    assert label.endswith("; not equal-budget)") and label not in ("ours", "mean", "photo")
    assert f"test set: 3 procedural materials (seed {TEST_SEED}); " in result.stdout
    rmse = _section(result.stdout, "RMSE")
    assert _rows(rmse, [label, "mean (baseline)", "photo (baseline)"]) == [
        label,
        "mean (baseline)",
        "photo (baseline)",
    ]
    parent = json.loads((out / "results.json").read_text())["parent_run"]
    children = _children(parent)
    assert set(children) == {label, "mean", "photo"}  # no fit
    assert children[label].data.tags["svbrdf.model_sha256"] == shipped.sha256
    assert children[label].data.tags["svbrdf.model_source"] == "pretrained"
    assert (
        "reference models only, each with the training budget its file records"
        in result.stdout.splitlines()[0]
    )
    assert "no model trained at this benchmark's budget" in result.stdout


def test_trained_strips_among_the_test_data_are_refused_then_allowed(folders, tmp_path):
    root, strips, _, model, _ = folders
    refused = _invoke("run", "--models", "ours", "--from-models", model, "--test-data", strips, *TINY,
                      "-o", tmp_path / "r")  # fmt: skip
    assert refused.exit_code == 2
    (err,) = _errors(refused)
    assert err.startswith(f"svbrdf-bench: error: --from-models {model}: 4 of the 6 test strips")
    assert "trained on" in err and "--allow-trained-strips" in err and "0000000;MatAXMatB;0X1.png" in err
    assert not _trained(refused.output) and not (tmp_path / "r").exists()  # refused before training
    allowed = _invoke("run", "--from-models", model, "--test-data", strips, *TINY, "--no-baselines",
                      "--allow-trained-strips", "-o", tmp_path / "r")  # fmt: skip
    assert allowed.exit_code == 0, allowed.output
    (record,) = json.loads((tmp_path / "r" / "results.json").read_text())["models"]
    assert record["model"] == LABEL[:-1] + "; trained on 4 of the 6 test strips)"
    assert record["reference_trained_test_strips"] == "4"
    assert "trained on 4 of the 6 test strips (--allow-trained-strips)" in allowed.stderr


def test_an_exported_fit_is_refused_on_the_strips_it_learnt(tmp_path):
    """What ``svbrdf-train export`` records (the names of the real strips) is what the guard reads."""
    strips = des18_strips(tmp_path / "strips", count=3)
    mix = "[{source: procedural, weight: 0.5}, {source: des18, weight: 0.5, validation: 0}]"
    fit = run_cli("fit", "--recipe", "ours-mix", "--size", "smoke", "--data", str(strips), "--out",
                  str(tmp_path / "fit"), "-q", "--no-track", "--set", f"data.mix={mix}")  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    exported = run_cli("export", str(tmp_path / "fit"), "-o", str(tmp_path / "m.pt"))
    assert exported.returncode == 0, exported.stderr
    result = _invoke("run", "--from-models", tmp_path / "m.pt", "--test-data", strips, *TINY)
    assert result.exit_code == 2
    (err,) = _errors(result)
    assert "3 of the 3 test strips" in err and "--allow-trained-strips" in err


def test_a_model_at_another_resolution_is_refused(tmp_path):
    tiny_model(tmp_path / "big.pt", resolution=64)
    result = _invoke(
        "run", "--models", "ours", "--from-models", tmp_path / "big.pt", *TINY, "-o", tmp_path / "r"
    )
    assert result.exit_code == 2
    (err,) = _errors(result)
    assert err.startswith(
        f"svbrdf-bench: error: --from-models {tmp_path / 'big.pt'}: the model runs at 64 px"
    )
    assert "tests at 32 px" in err and "'ours' at size 'smoke'" in err and "train.resolution=64" in err
    assert not _trained(result.output)


@pytest.mark.parametrize(
    ("flag", "make", "says"),
    [
        ("--from-models", None, "no model file there"),
        ("--from-models", "text", "not a readable model file"),
        ("--models", "pretrained:no-such-model", "pretrained:no-such-model: no such shipped model"),
    ],
)
def test_a_model_that_cannot_be_loaded_is_a_one_line_error(flag, make, says, tmp_path):
    source = make if make and make.startswith("pretrained") else str(tmp_path / "m.pt")
    if make == "text":
        (tmp_path / "m.pt").write_text("not a model\n")
    done = subprocess.run(
        [sys.executable, "-m", "svbrdf_bench", "run", "--models", "ours", flag, source, *TINY, "-o",
         str(tmp_path / "r")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    err = [line for line in done.stderr.splitlines() if " INFO mlflow." not in line and line.strip()]
    assert len(err) == 1 and "Traceback" not in done.stderr, done.stderr
    assert err[0].startswith(f"svbrdf-bench: error: {flag}: ") and says in err[0] and source in err[0]
    assert not _trained(done.stdout + done.stderr)


def test_a_new_store_is_made_without_mlflow_s_notices(tmp_path):
    """The first run on a store that does not exist yet prints the benchmark's lines, not MLflow's
    INFO lines about creating its tables."""
    env = dict(os.environ, MLFLOW_TRACKING_URI=f"sqlite:///{tmp_path / 'new.db'}")
    done = subprocess.run(
        [sys.executable, "-m", "svbrdf_bench", "run", "--models", "pretrained", "--test-count", "2",
         "--no-baselines", "--latency-grid", "256x1", "-o", str(tmp_path / "r")],
        capture_output=True, text=True, timeout=300, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "new.db").is_file() and (tmp_path / "r" / "results.json").is_file()
    assert "mlflow.store" not in done.stdout + done.stderr, done.stderr


def test_two_files_of_one_name_get_a_row_each(folders, tmp_path):
    _, _, judge, model, sha = folders
    (tmp_path / "other").mkdir()
    other_sha = tiny_model(tmp_path / "other" / "fold0.pt", seed=1)
    result = _invoke("run", "--from-models", f"{model},{tmp_path / 'other' / 'fold0.pt'}", "--test-data", judge,
                     *TINY, "--no-baselines", "-o", tmp_path / "r")  # fmt: skip
    assert result.exit_code == 0, result.output
    records = json.loads((tmp_path / "r" / "results.json").read_text())["models"]
    assert [r["reference_name"] for r in records] == ["fold0", f"fold0-{other_sha[:8]}"]
    assert [r["reference_sha256"] for r in records] == [sha, other_sha]


def test_help_documents_both_options_with_examples():
    text = _invoke("run", "--help").output
    assert "--from-models FILE|SOURCE,..." in text and "--allow-trained-strips" in text
    examples = [line.strip() for line in text.splitlines() if line.strip().startswith("svbrdf-bench run")]
    assert any("--from-models fold0.pt" in line for line in examples)
    assert any("--models pretrained" in line for line in examples)


@pytest.mark.parametrize(
    ("provenance", "words"),
    [
        ({"steps": 8300, "train_seconds": 3960.0, "device": "cpu"}, "ours, 128 px, 8.3k steps, 1.1 h CPU"),
        ({"steps": 250, "train_seconds": 1800.0, "device": "cuda:0", "hardware": "1 x NVIDIA H100 80GB HBM3"},
         "ours, 128 px, 250 steps, 30 min H100 80GB HBM3"),
        ({"steps": 2_500_000, "train_seconds": 90000.0, "device": "cuda", "world_size": 4,
          "hardware": "4 x NVIDIA H200"}, "ours, 128 px, 2.5M steps, 25.0 h 4 x H200"),
        ({}, "ours, 128 px, steps unknown, training time unknown"),
    ],
)  # fmt: skip
def test_budget_words(provenance, words):
    from types import SimpleNamespace

    from svbrdf_bench.references import budget_words

    model = SimpleNamespace(name="ours", resolution=128, precision="fp32", provenance=provenance,
                            steps=int(provenance.get("steps", 0)))  # fmt: skip
    assert budget_words(model) == words
    model.precision = "fp16"
    assert budget_words(model) == words + ", fp16"


def test_two_materials_are_said_to_be_too_few_with_per_strip_intervals(bench):
    """The two judged strips blend the same two materials: the report says its intervals over 2
    materials are unreliable, and counts its comparisons (each trained row against ``mean`` on
    5 columns, and the one pair of "what accuracy costs")."""
    out, result, _ = bench
    results = json.loads((out / "results.json").read_text())
    assert results["small_sample"].startswith("SMALL SAMPLE: 2 materials, fewer than 8")
    assert results["small_sample"] in result.stdout
    comparisons = results["comparisons"]
    assert comparisons["count"] == len(comparisons["verdicts"]) == 2 * len(COLUMNS) + 1
    assert f"{comparisons['count']} comparisons (verdicts) in this report" in result.stdout
    for v in comparisons["verdicts"]:
        assert 0 <= v["p_value"] <= v["holm_p"] <= 1 and v["survives_holm"] == (
            v["verdict"] == "within noise" or v["holm_p"] <= 0.05
        )
        assert v["per_strip"]["low"] <= v["per_strip"]["rmse_difference"] <= v["per_strip"]["high"]
    head = _section(result.stdout, "Verdicts: 11 comparisons")[1]
    assert "difference per material [95%]" in head and head.split()[-4:] == ["strip", "[95%]", "per", "strip"]
