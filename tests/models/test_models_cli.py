"""``svbrdf-models list`` and ``describe``: what a user sees, and errors as one line with exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from svbrdf_models.cli import main


def test_list_shows_every_kind_with_source(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("ours", "unet", "no-attn", "multiscale", "none", "se", "cbam", "patchgan", "multi"):
        assert any(line.split()[1:2] == [name] and "svbrdf-models" in line for line in out.splitlines()), name


def test_list_detail_reports_parameters_and_time(capsys):
    assert (
        main(
            [
                "list",
                "--kind",
                "attention",
                "--pattern",
                "se",
                "--detail",
                "--channels",
                "8",
                "--repeats",
                "1",
            ]
        )
        == 0
    )
    header, row = capsys.readouterr().out.strip().splitlines()
    assert "params" in header and "CPU ms" in header
    cells = row.split()
    assert cells[:3] == ["attention", "se", "svbrdf-models"]
    assert cells[3] == "144"  # two 1x1 convs 8 -> 8 -> 8 with biases
    assert float(cells[4]) > 0


def test_list_detail_builds_generators_with_a_preset(capsys):
    assert (
        main(
            [
                "list",
                "--kind",
                "generator",
                "--pattern",
                "ours",
                "--detail",
                "--preset",
                "tiny",
                "--repeats",
                "1",
            ]
        )
        == 0
    )
    row = capsys.readouterr().out.strip().splitlines()[1]
    assert row.split()[3].endswith("k")  # the tiny preset: thousands of parameters, not millions


def test_describe_prints_fields_and_presets(capsys):
    assert main(["describe", "ours"]) == 0
    out = capsys.readouterr().out
    assert "depth: int = 8" in out and "presets:" in out and "tiny" in out


def test_unknown_name_exits_2_with_one_line(capsys):
    assert main(["describe", "multiscal"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("svbrdf-models: error:") and "'multiscale'" in err and err.count("\n") == 1


def test_ambiguous_name_asks_for_kind(capsys):
    # 'multi' is a discriminator and a prefix of nothing else; 'none' is attention only.
    assert main(["describe", "none"]) == 0
    assert main(["describe", "none", "--kind", "generator"]) == 2
    assert "unknown generator 'none'" in capsys.readouterr().err


def test_console_script_help():
    r = subprocess.run(
        [sys.executable, "-m", "svbrdf_models.cli", "list", "--help"], capture_output=True, text=True
    )
    assert r.returncode == 0 and "examples:" in r.stdout and "--detail" in r.stdout


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["list", "--detail", "--channels", "0"], ["--channels", "from 1 to 4096", "got 0"]),
        (["list", "--detail", "--kind", "attention", "--channels", "100000"], ["--channels", "got 100000"]),
        (["list", "--detail", "--repeats", "0"], ["--repeats", "from 1 to 1000", "got 0"]),
        (["list", "--detail", "--repeats", "many"], ["--repeats", "'many'"]),
        (["list", "--kind", "generatr"], ["--kind", "'generatr'"]),
        # --detail's options without --detail, or where nothing listed reads them, did nothing
        (["list", "--repeats", "2"], ["--repeats 2", "add --detail"]),
        (["list", "--preset", "small"], ["--preset small", "add --detail"]),
        (["list", "--detail", "--kind", "generator", "--channels", "8"], ["--channels 8", "--kind attention"]),
        (["list", "--detail", "--preset", "smal"], ["--preset 'smal'", "'small'"]),
        (["list", "--detail", "--kind", "generator", "--pattern", "mean", "--preset", "tiny"], ["--preset 'tiny'", "Presets: none"]),
        (["list", "--pattern", "zzz*"], ["--pattern 'zzz*' matches no registered"]),
        (["describe"], ["name"]),
    ],
)
def test_bad_flags_exit_2_with_one_line_naming_them(argv, fragments, capsys):
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert err.startswith("svbrdf-models") and ": error: " in err and err.count("\n") == 1, err
    assert "Traceback" not in err and captured.out == ""  # refused before the table starts
    for fragment in fragments:
        assert fragment in err, (fragment, err)


def test_a_command_builds_only_its_own_parser_and_the_list_still_names_them_all(monkeypatch, capsys):
    from svbrdf_models import cli

    def must_not_build(sub):
        raise AssertionError("another command's parser was built")

    for name in ("list", "describe", "show", "serve"):
        monkeypatch.setitem(cli.PARSERS, name, must_not_build)
    assert main(["predict", "--help"]) == 0  # only predict's options are built
    assert "--refine" in capsys.readouterr().out
    monkeypatch.undo()
    assert main(["--help"]) == 0  # the whole list for the top level
    listed = capsys.readouterr().out
    assert all(name in listed for name in cli.PARSERS)
    assert main(["nosuch"]) == 2  # a bad name: every command offered
    err = capsys.readouterr().err
    assert all(repr(name) in err for name in cli.PARSERS)
