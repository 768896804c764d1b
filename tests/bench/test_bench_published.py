"""Published numbers beside a benchmark's rows (``svbrdf-bench run --published FILE.yaml``): the rows
in the terminal tables, report.md, results.json and the exported table, rebuilt from MLflow alone,
in no verdict; and every bad input refused in one line, exit 2, before any MLflow run is made.

One tiny benchmark (``ours`` at the smoke size, 32 px, on four Des18-named strips, with the
baselines so that the report has verdicts) runs once per module.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import des18_strips

from svbrdf_bench.cli import cli

TINY = ("--size", "smoke", "--latency-grid", "256x1", "--experiment", "tests-published")
#: The numbers of the file: made up for the test, not anyone's results.
ROWS = {
    "Alpha et al. 2018": {"normal": 0.0512, "diffuse": 0.0213, "roughness": 0.0634, "specular": 0.0217},
    "Beta et al. 2021": {"diffuse": 0.0301, "render": 0.1123},
}
FILE = f"""\
test_set: des18
protocol: {{crop: "centre crop 256 of the 288 px tile", resolution: 256, values: "[0, 1]",
           normals: "(n+1)/2", rmse: per image then mean, renderings: none}}
scorer: {{window: centre-crop, size: 48, values: "[0, 1]", rmse: per-image}}
rows:
  - {{name: "Alpha et al. 2018", source: "Venue A, Table 2", rmse: {json.dumps(ROWS["Alpha et al. 2018"])}}}
  - name: "Beta et al. 2021"
    source: "Venue B, Table 3"
    rmse: {json.dumps(ROWS["Beta et al. 2021"])}
    lpips: {{render: 0.21}}
    protocol: {{crop: "whole tile resized to 256 px"}}
"""
MARKED = [f"{name} (published, not rerun)" for name in ROWS]


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _client():
    from mlflow import MlflowClient

    return MlflowClient()


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    return des18_strips(tmp_path_factory.mktemp("des18") / "strips", count=4, size=64)


@pytest.fixture(scope="module")
def numbers(tmp_path_factory):
    path = tmp_path_factory.mktemp("published") / "papers.yaml"
    path.write_text(FILE)
    return path


@pytest.fixture(scope="module")
def bench(tmp_path_factory, strips, numbers):
    out = tmp_path_factory.mktemp("bench") / "report"
    result = _invoke("run", "--models", "ours", *TINY, "--test-data", strips, "--published", numbers, "-o", out)
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    return out, result, results


def _rmse_rows(text: str) -> dict[str, list[str]]:
    """The RMSE table's rows by name: the first cell up to two spaces, then the other cells."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("RMSE"))
    end = next(i for i in range(start, len(lines)) if not lines[i].strip())
    rows = {}
    for line in lines[start + 3 : end]:
        name, _, rest = line.partition("  ")
        rows[name.strip()] = rest.split()
    return rows


def test_the_rows_stand_in_the_rmse_table_without_interval(bench):
    _, result, _ = bench
    rows = _rmse_rows(result.stdout)
    assert list(rows)[:3] == ["ours", "mean (baseline)", "photo (baseline)"]
    assert list(rows)[3:] == MARKED
    for name, marked in zip(ROWS, MARKED, strict=True):
        expected = [f"{ROWS[name][c]:.4f}" if c in ROWS[name] else "-"
                    for c in ("normal", "diffuse", "roughness", "specular", "render")]  # fmt: skip
        assert rows[marked] == expected  # no interval: one figure per cell
    assert any("[" in cell for cell in rows["ours"])  # the rows scored here keep theirs
    assert "Venue A, Table 2" in result.stdout and "Venue B, Table 3" in result.stdout


def test_the_report_states_their_protocol_against_this_run_s(bench):
    out, result, results = bench
    published = results["published"]
    assert published["file"] == "papers.yaml" and published["test_set"] == "des18"
    assert published["marked"] == "published, not rerun"
    assert {r["name"]: r["rmse"] for r in published["rows"]} == ROWS
    assert [r["source"] for r in published["rows"]] == ["Venue A, Table 2", "Venue B, Table 3"]
    assert published["rows"][1]["lpips"] == {"render": 0.21}
    assert "32 px" in published["this_run"]["resolution"]  # the smoke size's, as scored
    checks = [{c["aspect"]: c["verdict"] for c in r["protocol_check"]} for r in published["rows"]]
    assert checks[0]["resolution"] == checks[1]["resolution"] == "differs"  # 256 against 32
    assert (checks[0]["crop"], checks[1]["crop"]) == ("differs", "same")  # the second row's own protocol
    assert checks[0]["rmse"] == "differs" and checks[0]["normals"] == "same"
    md = (out / "report.md").read_text()
    assert "## Published numbers (papers.yaml): their protocol against this run's" in md
    assert all(f"| {m} |" in md for m in MARKED)
    assert "Published numbers (papers.yaml)" in result.stdout
    if "LPIPS skipped" in result.stdout:  # Beta's LPIPS has no table to stand in: said, and in results.json
        assert "LPIPS of Beta et al. 2021: in results.json; this run computed no LPIPS" in result.stdout
    else:
        lpips = result.stdout.split("\nLPIPS", 1)[1].split("\n\n", 1)[0]
        assert MARKED[1] in lpips and MARKED[0] not in lpips


def _section(text: str, title: str) -> list[str]:
    """The lines of the terminal table titled ``title...`` up to the first empty line."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    return lines[start : next(i for i in range(start, len(lines)) if not lines[i].strip())]


def test_this_run_s_rows_are_scored_again_as_the_file_s_scorer_says(bench):
    out, result, results = bench
    scorer = results["published"]["scorer"]
    assert (scorer["window"], scorer["size"], scorer["rmse"]) == ("centre-crop", 48, "per-image")
    again = scorer["rows"]
    assert "ours" in again and len(again) == 3  # ours and the two baselines; no refined rows asked
    whole = {r["model"]: r for r in results["models"]}["ours"]
    for label, figures in again.items():
        assert set(figures) == {"normal", "diffuse", "roughness", "specular"}  # maps only
        assert all(0 <= v < 1 for v in figures.values()), (label, figures)
    assert again["ours"]["diffuse"] != pytest.approx(whole["rmse_diffuse"], rel=1e-6)  # another scoring
    table = _section(result.stdout, "Scored as the published rows (papers.yaml)")
    names = [line.split("  ")[0].strip() for line in table[3:]]
    assert names == [*again, *MARKED]
    alpha = table[3 + len(again)].split()[-4:]
    assert alpha == [f"{v:.4f}" for v in ROWS["Alpha et al. 2018"].values()]
    protocol = _section(result.stdout, "Published numbers (papers.yaml)")
    assert "this run, scored as published" in protocol[1]
    assert "centre 48 px of each stored tile" in "\n".join(protocol)
    assert "## Scored as the published rows (papers.yaml)" in (out / "report.md").read_text()


def test_they_take_no_part_in_verdicts_costs_or_the_front(bench):
    _, _, results = bench
    names = set(ROWS) | set(MARKED)
    verdicts = results["comparisons"]["verdicts"]
    assert verdicts  # the report does judge: ours against mean
    assert not {v["model"] for v in verdicts} & names and not {v["versus"] for v in verdicts} & names
    assert not {r["model"] for r in results["models"]} & names
    assert not set(results["latency_front"]["front"]) & names
    assert not {r["model"] for r in results["against_mean"]} & names


def test_the_parent_run_keeps_the_file_and_report_rebuilds_the_rows(bench, numbers, tmp_path):
    _, result, results = bench
    parent = results["parent_run"]
    client = _client()
    assert client.get_run(parent).data.params["published_file"] == "papers.yaml"
    local = client.download_artifacts(parent, "eval/published.yaml", str(tmp_path))
    assert Path(local).read_text() == numbers.read_text()
    again = _invoke("report", parent, "-o", tmp_path / "again")
    assert again.exit_code == 0, again.output
    assert _rmse_rows(again.stdout) == _rmse_rows(result.stdout)
    rebuilt = json.loads((tmp_path / "again" / "results.json").read_text())
    assert rebuilt["published"] == results["published"]  # the rows scored as published too
    assert rebuilt["published"]["scorer"]["rows"]


def test_export_marks_them_in_markdown_and_latex(bench):
    parent = bench[2]["parent_run"]
    md = _invoke("export", parent, "--format", "markdown")
    assert md.exit_code == 0, md.output
    lines = md.stdout.splitlines()
    assert "Rows marked published, not rerun" in lines[0] and "differs from this table's in resolution" in lines[0]
    alpha = next(line for line in lines if line.startswith(f"| {MARKED[0]} |"))
    assert alpha.split(" | ")[1:] == ["0.051", "0.021", "0.063", "0.022", "- |"]  # no interval, no bold
    assert lines.index(alpha) == len(lines) - 2  # after the rows scored here
    again = [line for line in lines if "(scored as published)" in line]
    assert again and again[0].startswith("| ours (scored as published) |") and again[0].endswith("| - |")
    assert lines.index(again[-1]) == lines.index(alpha) - 1 and "Rows marked scored as published" in lines[0]
    tex = _invoke("export", parent, "--format", "latex")
    assert tex.exit_code == 0, tex.output
    body = tex.stdout.splitlines()
    beta = next(i for i, line in enumerate(body) if line.startswith("Beta et al. 2021 (published, not rerun) &"))
    assert body[beta] == r"Beta et al. 2021 (published, not rerun) & - & 0.030 & - & - & 0.112 \\"
    assert body[beta - 2] == r"\midrule" and body[beta + 1] == r"\bottomrule"


# -- refusals: one line, exit 2, nothing made in MLflow ---------------------------------------------


def _refused(args, experiment: str) -> str:
    """The one line of a refused run; checks that no MLflow run exists under ``experiment``."""
    result = _invoke("run", "--models", "ours", "--size", "smoke", "--experiment", experiment, *args)
    assert result.exit_code == 2, result.output
    err = [line for line in result.stderr.splitlines() if " INFO mlflow." not in line and line.strip()]
    assert len(err) == 1 and err[0].startswith("svbrdf-bench: error: --published"), result.stderr
    found = _client().get_experiment_by_name(experiment)
    assert found is None or not _client().search_runs([found.experiment_id]), "a run was made"
    return err[0]


def test_des18_by_name_is_refused_no_numbers_ship(strips):
    line = _refused(["--test-data", strips, "--published", "des18"], "tests-published-name")
    assert "ships no published numbers for des18" in line and "--published FILE.yaml" in line
    assert "docs/svbrdf-bench.md" in line


@pytest.mark.parametrize("path", ["missing.yaml", "."])
def test_an_unreadable_path_is_refused(strips, tmp_path, path):
    line = _refused(["--test-data", strips, "--published", tmp_path / path], "tests-published-path")
    assert "cannot read it" in line


def test_numbers_on_another_test_set_than_the_run_s_are_refused(strips, numbers):
    line = _refused(["--test-count", "2", "--published", numbers], "tests-published-procedural")
    assert "its numbers are on des18" in line and "procedural" in line
    line = _refused(["--test-data", strips, "--group-by", "file", "--published", numbers], "tests-published-file")
    assert "grouped by file" in line


BAD = {
    "no rows": ("rows:", "no rows"),
    "empty rows": ("rows: []", "rows must be a non-empty list"),
    "unknown map": ('rmse: {"normal": 0.0512', 'rmse: {"albedo": 0.0512', "rmse.albedo: unknown map"),
    "negative": ("0.0213", "-0.0213", "is -0.0213"),
    "not finite": ("0.0213", ".nan", "is nan"),
    "infinite": ("0.0634", ".inf", "is inf"),
    "no source": ('source: "Venue A, Table 2", ', "", "has no source"),
    "other test set": ("test_set: des18", "test_set: des19", "test_set 'des19' is not one"),
    "not YAML": ("rows:\n", "rows: [\n", "not valid YAML"),
    "scorer window": ("window: centre-crop", "window: corner", "scorer.window is 'corner'"),
    "scorer size": ("size: 48", "size: 4.5", "scorer.size is 4.5"),
    "scorer key": ("rmse: per-image}", "rmse: per-image, gamma: 2.2}", "scorer: unknown key 'gamma'"),
    "scorer missing": ('values: "[0, 1]", rmse: per-image', "rmse: per-image", "scorer has no values"),
    "tiles smaller": ("size: 48", "size: 96", "are smaller (the smallest 64 px)"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_malformed_file_is_refused(strips, tmp_path, case):
    *edit, message = BAD[case]
    text = FILE.split("\nrows:")[0] + "\n" if case == "no rows" else FILE
    if case == "empty rows":
        text = FILE.split("\nrows:")[0] + "\nrows: []\n"
    elif len(edit) == 2:
        assert edit[0] in FILE
        text = FILE.replace(edit[0], edit[1], 1)
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    line = _refused(["--test-data", strips, "--published", path], f"tests-published-{case.replace(' ', '-')}")
    assert message in line, line
