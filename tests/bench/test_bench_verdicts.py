"""How far the report's verdicts can be trusted, on per-sample figures made up here: Holm's
correction on a hand-worked example, the bootstrap p-value, verdicts that do not survive Holm
marked in the tables and the headline, the warning and the per-strip intervals on a test set of
few materials; and the paper table (``export_table``) in Markdown and LaTeX."""

from __future__ import annotations

import re

import numpy as np
import pytest

from svbrdf_bench.errors import BenchError
from svbrdf_bench.metrics import bootstrap_p_value, holm, holm_adjusted, paired_difference
from svbrdf_bench.report import (
    COLUMNS,
    ModelEntry,
    Report,
    export_table,
    family,
    headline,
    markdown,
    small_sample_note,
    table_lines,
    terminal,
)
from svbrdf_bench.report.tables import against_table, verdict_table

# -- Holm and the p-value -----------------------------------------------------------------------


def test_holm_on_a_hand_worked_example():
    """p = 0.01, 0.04, 0.03, 0.005 at alpha 0.05 (m = 4). Sorted: 0.005 <= 0.05/4 = 0.0125 kept;
    0.01 <= 0.05/3 = 0.0167 kept; 0.03 > 0.05/2 = 0.025: stop, so 0.03 and 0.04 fall too.
    Adjusted: 4 * 0.005 = 0.02, 3 * 0.01 = 0.03, max(0.03, 2 * 0.03) = 0.06, max(0.06, 0.04) = 0.06."""
    p = [0.01, 0.04, 0.03, 0.005]
    assert holm(p, alpha=0.05) == [True, False, False, True]
    assert holm_adjusted(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.03], alpha=0.05) == [True]  # one comparison: the test itself
    assert holm([0.03, 0.03], alpha=0.05) == [False, False]  # 2 * 0.03 > 0.05
    assert holm([]) == []
    for bad in ([0.5, float("nan")], [1.5]):
        with pytest.raises(BenchError, match="p-values must lie in"):
            holm(bad)


def test_the_p_value_is_twice_the_share_of_resamples_beyond_zero():
    assert bootstrap_p_value(np.array([-3.0, -2.0, -1.0, 1.0])) == pytest.approx(0.5)  # 2 * 1/4
    assert bootstrap_p_value(np.array([-1.0, -1.0, 1.0, 2.0])) == 1.0
    assert bootstrap_p_value(np.zeros(10)) == 1.0  # identical figures: no evidence
    assert bootstrap_p_value(None) == 1.0  # one test image: nothing to resample
    rng = np.random.default_rng(3)
    b = rng.random(30)
    clear = paired_difference(b - 0.1, b)
    assert clear.p_value == 0.0 and not clear.within_noise
    same = paired_difference(b, b)
    assert same.p_value == 1.0 and same.within_noise
    for seed in range(6):  # the p-value and the 95% interval come from the same resamples
        d = paired_difference(b + 0.05 * np.random.default_rng(seed).standard_normal(30), b)
        if abs(d.p_value - 0.05) > 0.01:  # away from the interpolation at the edge
            assert (d.p_value < 0.05) == (not d.within_noise), d


# -- synthetic reports --------------------------------------------------------------------------


def _entry(label: str, values: dict[str, np.ndarray], baseline: bool = False) -> ModelEntry:
    per_sample = {f"rmse/{c}": np.asarray(v, dtype=np.float64) for c, v in values.items()}
    return ModelEntry(label, f"run-{label}", f"run-{label}", per_sample, {}, baseline=baseline)


def _weak_report() -> Report:
    """One model, better than ``mean`` on 27 of 40 images by the same step on every column: each
    verdict beats at 95% (p about 0.02), none survives Holm over its 5 comparisons."""
    base = 0.1 + 0.01 * np.random.default_rng(0).random(40)
    step = np.where(np.arange(40) < 27, -0.001, 0.001)
    models = [_entry("weak", {c: base + step for c in COLUMNS}),
              _entry("mean", {c: base for c in COLUMNS}, True)]  # fmt: skip
    return Report("parent", "quick", "40 procedural materials", "LPIPS skipped", "2 min", models)


def test_a_verdict_that_does_not_survive_holm_says_so():
    report = _weak_report()
    fam = family(report)
    assert fam.count == 5
    for v in fam.verdicts:
        assert v.verdict == "beats" and 0 < v.p_value < 0.05 < v.holm_p and not v.survives
    cells = table_lines(against_table(report), False)[3].split("  ")
    assert sum("beats, but not after Holm over 5 comparisons" in c for c in cells) == 5
    (line,) = headline(report)
    assert line.startswith("weak beats the constant-map baseline `mean` on every map")
    assert line.endswith(
        "After Holm over 5 comparisons, its verdicts on normal (beats), diffuse (beats), roughness (beats), "
        "specular (beats), render (beats) do not hold."
    )
    text = terminal(report)
    assert "5 comparisons (verdicts) in this report" in text
    assert "5 of the 5 verdicts beyond noise do not survive (weak vs mean (baseline) on normal, " in text
    table = table_lines(verdict_table(report), False)
    assert table[0].startswith("Verdicts: 5 comparisons, corrected together by Holm at 5%")
    assert all(row.rstrip().endswith("beats, but not after Holm over 5 comparisons") for row in table[3:])


def test_the_family_is_computed_once_per_set_of_rows():
    report = _weak_report()
    fam = family(report)
    assert family(report) is fam  # every section asks; the bootstraps run once
    report.models[0].per_sample = {k: v - 0.02 for k, v in report.models[1].per_sample.items()}
    again = family(report)  # other figures: computed anew
    assert again is not fam and all(v.survives for v in again.verdicts)
    assert not any(v.survives for v in fam.verdicts)


def test_a_clear_verdict_survives_and_keeps_its_words():
    report = _weak_report()
    report.models[0].per_sample = {k: v - 0.02 for k, v in report.models[1].per_sample.items()}
    fam = family(report)
    assert all(v.survives and fam.words(v) == "beats" for v in fam.verdicts)
    assert "all 5 verdicts beyond noise survive" in terminal(report)
    assert "Holm" not in headline(report)[0]


def _grouped(materials: int, strips_per_pair: int = 1) -> Report:
    """A Des18-like test set: strips blending pairs of ``materials`` materials."""
    names = [f"m{i}" for i in range(materials)]
    groups = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]] * strips_per_pair
    rng = np.random.default_rng(1)
    base = 0.1 + 0.02 * rng.random(len(groups))
    model = base - 0.01 + 0.005 * rng.standard_normal(len(groups))
    models = [_entry("ours", {c: model for c in COLUMNS}), _entry("mean", {c: base for c in COLUMNS}, True)]
    return Report("parent", "quick", "des18-dev", "LPIPS skipped", "2 min", models, groups=groups,
                  sample_names=[f"s{i}" for i in range(len(groups))], group_by="des18")  # fmt: skip


def test_few_materials_are_said_in_words_with_per_strip_intervals_beside():
    report = _grouped(4, strips_per_pair=3)  # 18 strips of 4 materials, as des18-dev
    note = small_sample_note(report)
    assert note.startswith("SMALL SAMPLE: 4 materials, fewer than 8: intervals and verdicts over so few")
    assert "only 35 distinct resamples" in note and "p = 0.125" in note and "18 strips" in note
    assert note in terminal(report) and f"**{note}**" in markdown(report, {})
    table = table_lines(verdict_table(report), False)
    assert "per strip [95%]" in table[1] and "difference per material [95%]" in table[1]
    for v in family(report).verdicts:
        a, b = (e.per_sample[f"rmse/{v.column}"] for e in report.models)
        strip = paired_difference(a, b)  # over the 18 strips, not the 4 materials
        assert (v.strips.low, v.strips.high) == (strip.low, strip.high)
        assert v.strips.high - v.strips.low != pytest.approx(v.high - v.low)


def test_enough_materials_need_no_warning():
    report = _grouped(10)  # 45 strips of 10 materials
    assert small_sample_note(report) is None and "SMALL SAMPLE" not in terminal(report)
    assert all(v.strips is None for v in family(report).verdicts)
    assert "per strip" not in table_lines(verdict_table(report), False)[1]
    few_images = _weak_report()
    for e in few_images.models:
        e.per_sample = {k: v[:5] for k, v in e.per_sample.items()}
    note = small_sample_note(few_images)  # ungrouped: each image its own material, nothing per strip
    assert note.startswith("SMALL SAMPLE: 5 test images (each its own material)") and "Per-strip" not in note


# -- the paper table ----------------------------------------------------------------------------


def _paper_report() -> Report:
    """des18-dev-like: ``ours`` best on every column but diffuse, where ``mean`` is; ``no_attn``
    (a name to escape) a little worse than ``ours``; ``photo`` worst."""
    report = _grouped(4, strips_per_pair=3)
    ours, mean = report.models
    ours.per_sample["rmse/diffuse"] = mean.per_sample["rmse/diffuse"] + 0.01
    rival = _entry("no_attn", {c: ours.per_sample[f"rmse/{c}"] + 0.003 for c in COLUMNS})
    photo = _entry("photo", {c: ours.per_sample[f"rmse/{c}"] + 0.05 for c in COLUMNS}, True)
    report.models = [ours, rival, mean, photo]
    return report


def test_markdown_export_bolds_the_best_of_each_column_and_keeps_the_baselines():
    report = _paper_report()
    text = export_table(report, "markdown")
    lines = text.splitlines()
    assert lines[0].startswith("**Table.** RMSE (lower is better) on des18-dev: 4 materials (18 strips")
    assert "95% percentile-bootstrap interval over materials" in lines[0]
    assert "`mean`: constant maps" in lines[0]
    assert lines[2] == "| model | normal | diffuse | roughness | specular | render |"
    rows = {line.split(" | ")[0][2:]: line.split(" | ")[1:] for line in lines[4:]}
    assert list(rows) == ["ours", "no_attn", "mean (baseline)", "photo (baseline)"]
    best = dict.fromkeys(COLUMNS, "ours") | {"diffuse": "mean (baseline)"}
    for i, c in enumerate(COLUMNS):
        bold = [name for name, cells in rows.items() if cells[i].startswith("**")]
        assert bold == [best[c]], c
        mean, low, high = report.interval(next(e for e in report.models if e.name == best[c]), "rmse", c)
        assert rows[best[c]][i].strip(" |") == f"**{mean:.3f}** [{low:.3f}, {high:.3f}]"


def test_with_seeds_a_model_is_one_row_over_its_seeds():
    from svbrdf_bench.report.seedstats import hierarchical_bootstrap

    report = _paper_report()
    ours, rival, mean, photo = report.models
    for seed, e in enumerate((ours, rival)):  # two seeds of one model
        e.label, e.seed, e.method = f"ours (seed {seed})", seed, "ours"
    lines = export_table(report, "markdown").splitlines()
    assert "2 seeds per model (a model's figure: the mean over its seeds" in lines[0]
    rows = [line.split(" | ")[0][2:] for line in lines[4:]]
    assert rows == ["ours (2 seeds)", "mean (baseline)", "photo (baseline)"]
    values = np.stack([report.values(e, "rmse/render") for e in (ours, rival)])  # (seeds, materials)
    mean_, low, high = hierarchical_bootstrap(values)
    assert lines[4].endswith(f" | **{mean_:.3f}** [{low:.3f}, {high:.3f}] |")  # render: the best


def test_latex_export_is_a_booktabs_table_with_escapes():
    text = export_table(_paper_report(), "latex")
    lines = text.splitlines()
    assert lines[0].startswith("% svbrdf-bench export parent --format latex; needs \\usepackage{booktabs}")
    body = [line for line in lines if not line.startswith("%")]
    order = [r"\begin{table}", r"\begin{tabular}{lccccc}", r"\toprule", r"\midrule", r"\bottomrule",
             r"\end{tabular}", r"\end{table}"]  # fmt: skip
    found = [next(i for i, line in enumerate(body) if line.startswith(o)) for o in order]
    assert found == sorted(found)
    assert "no\\_attn & " in text and "no_attn" not in text.replace("no\\_attn", "")
    assert re.search(r"(?<!\\)%", "\n".join(body)) is None  # every % escaped outside the comment
    assert "95\\% percentile-bootstrap" in text and "\\texttt{mean}" in text and "`" not in text
    rows = body[body.index(r"\toprule") + 3 : body.index(r"\bottomrule")]
    assert rows[2] == r"\midrule" and rows[3].startswith("mean (baseline) & ")  # baselines apart
    assert sum(row.count(r"\textbf{") for row in rows) == 5  # one best per column
    assert rows[2 + 1].count(r"\textbf{") == 1  # mean's diffuse
    assert all(row.endswith(r" \\") and row.count("&") == 5 for row in rows if row != r"\midrule")
    assert "\n".join(body).count("{") == "\n".join(body).count("}")


def test_an_unknown_export_format_is_refused():
    with pytest.raises(BenchError, match="unknown export format 'html': choose one of latex, markdown"):
        export_table(_paper_report(), "html")


def test_the_latex_export_compiles(tmp_path):
    """In an article with booktabs, where a LaTeX is installed (pdflatex)."""
    import shutil
    import subprocess

    if shutil.which("pdflatex") is None:
        pytest.skip("pdflatex not installed")
    (tmp_path / "table.tex").write_text(export_table(_paper_report(), "latex"))
    (tmp_path / "doc.tex").write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n"
        "\\input{table.tex}\n\\end{document}\n"
    )
    r = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "doc.tex"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:]
    assert (tmp_path / "doc.pdf").stat().st_size > 0
