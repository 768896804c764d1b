"""The predict options are declared once (issue 38): ``svbrdf-train predict`` takes
``svbrdf-models predict``'s options, parsed by the same declaration
(``svbrdf_models.commands.predict.add_options``), plus its own --checkpoint and --run; its one
difference is the --refine default (0, where svbrdf-models' is 100), said in both helps."""

from __future__ import annotations

import re
import tokenize
from pathlib import Path

import pytest
from click.testing import CliRunner

from svbrdf_models.cli import main as models_main
from svbrdf_render import DEFAULT_REFINE_STEPS
from svbrdf_train.cli import cli as train_cli

REPO = Path(__file__).resolve().parents[1]
#: An option's invocation in a help listing: "  -o OUT, --out OUT    output folder".
_INVOCATION = re.compile(r"^  (-\S.*?)(?:\s{2,}|$)")


def _help(prog: str, capsys) -> str:
    if prog == "svbrdf-models":
        assert models_main(["predict", "--help"]) == 0
        return capsys.readouterr().out
    result = CliRunner().invoke(train_cli, ["predict", "--help"])
    assert result.exit_code == 0, result.output
    return result.stdout


def _options(text: str) -> set[str]:
    """The option strings a help lists (the invocations, not the words of the help texts)."""
    found = set()
    for line in text.splitlines():
        match = _INVOCATION.match(line)
        if match:
            found |= set(re.findall(r"(?<![\w-])--?[A-Za-z][\w-]*", match.group(1)))
    return found


def test_svbrdf_train_predict_takes_svbrdf_models_options_and_its_own_two(capsys):
    models, train = _help("svbrdf-models", capsys), _help("svbrdf-train", capsys)
    assert {
        "-o",
        "--out",
        "--model",
        "--refine",
        "--crop",
        "--map-size",
        "--reference",
        "--threads",
    } <= _options(models)
    assert _options(train) == _options(models) | {"--checkpoint", "--run"}
    assert f"(default: {DEFAULT_REFINE_STEPS}; svbrdf-train predict's is 0;" in " ".join(models.split())
    assert (
        f"(default: 0; svbrdf-models predict refines by default, {DEFAULT_REFINE_STEPS} steps)"
        in " ".join(train.split())
    )


ARGV = ["a.png", "b.jpg", "-o", "maps", "--model", "m.pt", "--refine", "7", "--reference", "1,2,30,40:0.18",
        "--refine-seconds", "2.5", "--backend", "eager", "--linear", "--crop", "1,2,300", "--tiles",
        "--map-size", "full", "--normal", "DX", "--bits", "16", "--albedo-encoding", "srgb", "--exr",
        "--tileable", "--relit", "png", "--device", "auto", "--threads", "3", "--metal", "none"]  # fmt: skip


@pytest.mark.parametrize("argv", [ARGV, ["a.png", "-o", "maps"]], ids=["every option", "defaults"])
def test_both_commands_parse_the_same_values_and_capture_options(argv):
    """The same command line gives the same values and the same CaptureOptions in both commands,
    but for the --refine default."""
    from svbrdf_models.cli import build_parser
    from svbrdf_models.commands.predict import _capture_options
    from svbrdf_train.commands.predict import build_parser as train_parser

    models = vars(build_parser().parse_args(["predict", *argv]))
    train = vars(train_parser().parse_args(argv))
    assert (train.pop("checkpoint"), train.pop("run"), models.pop("command")) == (None, None, "predict")
    if "--refine" not in argv:
        assert (models.pop("refine"), train.pop("refine")) == (DEFAULT_REFINE_STEPS, 0)
    assert models == train
    if "--refine" in argv:
        from argparse import Namespace

        assert _capture_options(Namespace(**models)) == _capture_options(Namespace(**train))


def test_a_photo_named_like_an_option_is_taken_after_a_double_dash_by_both_commands(monkeypatch):
    """``-- -x.jpg``: both commands see a photo named -x.jpg (click drops ``--`` unless the
    command keeps its arguments as typed)."""
    from click.testing import CliRunner

    import svbrdf_models.commands.predict as models_predict
    from svbrdf_models.cli import main as models_main
    from svbrdf_train.cli import cli as train_cli

    seen = []
    monkeypatch.setattr(models_predict, "run_predict", lambda args, load, prog: seen.append(list(map(str, args.photos))) or 0)
    assert models_main(["predict", "-o", "maps", "--", "-x.jpg"]) == 0
    result = CliRunner().invoke(train_cli, ["predict", "-o", "maps", "--", "-x.jpg"])
    assert result.exit_code == 0, result.output
    assert seen == [["-x.jpg"], ["-x.jpg"]]


def _strings_containing(text: str) -> list[str]:
    """``path:line`` of every string token of the four packages' source (f-string parts too)
    that holds ``text``, letter case aside."""
    kinds = {tokenize.STRING, getattr(tokenize, "FSTRING_MIDDLE", tokenize.STRING)}
    out = []
    for path in sorted((REPO / "packages").glob("*/src/*/**/*.py")):
        if "/build/" in str(path):
            continue
        with path.open("rb") as f:
            out += [
                f"{path.relative_to(REPO)}:{tok.start[0]}"
                for tok in tokenize.tokenize(f.readline)
                if tok.type in kinds and text.lower() in tok.string.lower()
            ]
    return out


@pytest.mark.parametrize(
    "text",
    [
        "the square to capture, in pixels of the photo as displayed",  # --crop's help
        "expected X,Y,SIZE (three integers in pixels)",  # --crop's refusal
        "stores the normal's y (green) flipped",  # --normal's help
        "the capture's scene (YAML) to refine under",  # --scene's help
        "refinement steps per photo",  # --refine's help
    ],
)
def test_the_predict_help_texts_are_written_once(text):
    found = _strings_containing(text)
    assert len(found) == 1 and found[0].startswith(
        "packages/svbrdf-models/src/svbrdf_models/commands/predict.py:"
    ), found
