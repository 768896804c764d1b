"""``svbrdf-train predict``: maps from photos with a smoke checkpoint, from its file or its MLflow run.

One smoke fit per module (a few seconds) gives the checkpoint. Predictions run the command in a
fresh process, against the suite's temporary MLflow store; refused arguments run it in-process.
"""

from __future__ import annotations

import json

import pytest
import torch
import torch.nn.functional as F
from click.testing import CliRunner

from conftest import run_cli
from svbrdf_models.capture.photos import square_photo
from svbrdf_render import read_image, write_image
from svbrdf_render.formats.mapfiles import linear_to_srgb, srgb_to_linear
from svbrdf_train.cli import cli
from svbrdf_train.data import ProceduralMaterials
from svbrdf_train.predict import Predictor

MAPS = ("normal", "diffuse", "roughness", "specular")
#: What capture writes besides the maps (see test_train_capture.py for their content).
FIGURES = ("input.png", "rerender.png", "relit.gif", "basecolor.png", "metallic.png", "metallic_roughness.png",
           "material.json", "material.gltf", "material.mtlx", "index.html")  # fmt: skip
EIGHT_BIT = 1 / 255 + 1e-6


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "ours-smoke"
    result = run_cli("fit", "--recipe", "ours", "--size", "smoke", "--out", str(out), "-q")
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="module")
def checkpoint(fit_dir):
    return fit_dir / "last.pt"


@pytest.fixture(scope="module")
def run_id(fit_dir):
    return json.loads((fit_dir / "last.json").read_text())["run_id"]


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """Two procedural flash photos, 96 wide and 72 high (capture refuses fewer than 64 px on the short
    side), sRGB-encoded as cameras save them."""
    folder = tmp_path_factory.mktemp("photos")
    data = ProceduralMaterials(2, 96, seed=5)
    return [
        write_image(folder / f"shot{i}.png", linear_to_srgb(data[i]["input"][:, 12:84, :])) for i in range(2)
    ]


@pytest.fixture(scope="module")
def by_checkpoint(tmp_path_factory, checkpoint, photos):
    """``predict`` both photos with ``--checkpoint``: (output folder, completed process)."""
    out = tmp_path_factory.mktemp("predicted") / "maps"
    result = run_cli("predict", *map(str, photos), "--checkpoint", str(checkpoint), "-o", str(out))
    assert result.returncode == 0, result.stderr
    return out, result


def _refused(*args):
    """``svbrdf-train predict ARGS`` in-process, for arguments refused before any prediction."""
    result = CliRunner().invoke(cli, ["predict", *map(str, args)])
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception  # a traceback in a real run
    return result


def _read_maps(folder):
    """The four written maps as stored: normal (n+1)/2 (3 channels), roughness grey (1 channel)."""
    return {
        name: read_image(folder / f"{name}.png", channels=1 if name == "roughness" else 3) for name in MAPS
    }


def _encoded(svbrdf):
    """What ``predict`` should store for an in-process prediction (batch of one): albedos
    sRGB-encoded (the default for texture tools)."""
    return {
        "normal": ((F.normalize(svbrdf.normal, dim=1) + 1) / 2)[0],
        "diffuse": linear_to_srgb(svbrdf.diffuse[0]),
        "roughness": svbrdf.roughness[0],
        "specular": linear_to_srgb(svbrdf.specular[0]),
    }


def _max_diff(a, b):
    return float((a - b).abs().max())


def test_predict_from_checkpoint_writes_the_maps_the_predictor_gives(checkpoint, photos, by_checkpoint):
    """Each photo gets NAME/{normal,diffuse,roughness,specular,input}.png at the training resolution
    (32 px for smoke, from a 96x72 photo), with the capture figures; the maps are what Predictor.predict gives in-process,
    normals decode to unit vectors facing the camera, and input.png is the sRGB centre square."""
    out, result = by_checkpoint
    assert result.returncode == 0, result.stderr
    assert "32x32" in result.stderr and str(checkpoint) in result.stderr
    assert result.stdout.split() == [str(out / p.stem) for p in photos]
    assert sorted(p.name for p in out.iterdir()) == sorted([*(p.stem for p in photos), "summary.json"])
    predictor = Predictor.from_checkpoint(checkpoint)
    assert predictor.resolution == 32
    for path in photos:
        folder = out / path.stem
        assert sorted(p.name for p in folder.iterdir()) == sorted([*(f"{n}.png" for n in MAPS), *FIGURES])
        written = _read_maps(folder)
        assert {n: tuple(t.shape) for n, t in written.items()} == {
            "normal": (3, 32, 32),
            "diffuse": (3, 32, 32),
            "roughness": (1, 32, 32),
            "specular": (3, 32, 32),
        }
        n = written["normal"] * 2 - 1
        assert float((n.norm(dim=0) - 1).abs().max()) < 0.02
        assert bool((n[2] > 0).all())
        photo = srgb_to_linear(read_image(path))
        expected = _encoded(predictor.predict(photo))
        for name in MAPS:
            assert _max_diff(written[name], expected[name]) <= EIGHT_BIT, name
        shown = read_image(folder / "input.png")
        assert shown.shape == (3, 32, 32)
        assert _max_diff(shown, linear_to_srgb(square_photo(photo, 32))) <= EIGHT_BIT
    # the two photos differ, and so do their maps: the output is not one constant image
    a, b = (_read_maps(out / p.stem)["diffuse"] for p in photos)
    assert _max_diff(a, b) > 0.01


def test_predict_from_run_matches_the_checkpoint(tmp_path, run_id, photos, by_checkpoint):
    """--run RUN_ID downloads the run's logged checkpoint from MLflow: the same maps as --checkpoint."""
    by_file, by_run = by_checkpoint[0], tmp_path / "run"
    result = run_cli("predict", str(photos[0]), "--run", run_id, "-o", str(by_run))
    assert result.returncode == 0, result.stderr
    assert f"run {run_id}" in result.stderr
    name = photos[0].stem
    for png in (*MAPS, "input"):
        a = read_image(by_file / name / f"{png}.png")
        b = read_image(by_run / name / f"{png}.png")
        assert torch.equal(a, b), (png, float((a - b).abs().max()), result.stderr)


def test_unreadable_photos_are_reported_and_the_others_done(tmp_path, checkpoint, photos):
    """A text file named .png and a missing file are each named on stderr; the good photo between
    them is still written; the exit code is 1 (some failed, not all)."""
    bad = tmp_path / "x.png"
    bad.write_text("not an image\n")
    missing = tmp_path / "gone.png"
    out = tmp_path / "maps"
    result = run_cli(
        "predict", str(bad), str(photos[1]), str(missing), "--checkpoint", str(checkpoint), "-o", str(out)
    )
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("svbrdf-train: error: ")]
    assert len(errors) == 2
    assert str(bad) in errors[0] and "cannot decode" in errors[0]
    assert str(missing) in errors[1]
    assert "2 of 3 photo(s) failed" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == [photos[1].stem, "summary.json"]
    assert sorted(p.name for p in (out / photos[1].stem).iterdir()) == sorted(
        [*(f"{n}.png" for n in MAPS), *FIGURES]
    )


@pytest.mark.parametrize("how", ["checkpoint and run", "model and checkpoint", "all three"])
def test_one_model_at_most(tmp_path, checkpoint, run_id, photos, how):
    """At most one of --model, --checkpoint and --run: otherwise a one-line error, exit 2, nothing written."""
    given = {
        "checkpoint and run": ["--checkpoint", checkpoint, "--run", run_id],
        "model and checkpoint": ["--model", "pretrained", "--checkpoint", checkpoint],
        "all three": ["--model", "pretrained", "--checkpoint", checkpoint, "--run", run_id],
    }[how]
    result = _refused(photos[0], *given, "-o", tmp_path / "maps")
    assert result.exit_code == 2
    assert result.stderr.startswith("svbrdf-train: error: ") and result.stderr.count("\n") == 1
    assert all(flag in result.stderr for flag in ("--model", "--checkpoint", "--run"))
    assert not (tmp_path / "maps").exists()


def _not_a_checkpoint(tmp_path, fit_dir, kind):
    if kind == "recipe file":
        return fit_dir / "recipe.yaml"
    if kind == "another tool's torch file":
        path = tmp_path / "weights.pt"
        torch.save({"state_dict": {"w": torch.zeros(2)}}, path)
        return path
    if kind == "checkpoint whose recipe has no generator":
        path = tmp_path / "last.pt"
        torch.save({"format": 1, "step": 3, "recipe": {"name": "ours"}, "generator": {}}, path)
        return path
    return tmp_path / "nowhere.pt"


@pytest.mark.parametrize(
    "kind",
    [
        "recipe file",
        "another tool's torch file",
        "missing file",
        "checkpoint whose recipe has no generator",
    ],
)
def test_checkpoint_that_is_not_one(tmp_path, fit_dir, photos, kind):
    """--checkpoint at a file that is no svbrdf-train checkpoint: exit 2, the error names the file,
    nothing written."""
    path = _not_a_checkpoint(tmp_path, fit_dir, kind)
    result = _refused(photos[0], "--checkpoint", path, "-o", tmp_path / "maps")
    assert result.exit_code == 2
    assert result.stderr.startswith(f"svbrdf-train: error: {path}: ")
    assert not (tmp_path / "maps").exists()


def test_checkpoint_error_is_one_line(tmp_path, fit_dir, photos):
    """The error for a file torch cannot unpickle (here the recipe YAML) is one line, like every other."""
    path = fit_dir / "recipe.yaml"
    result = _refused(photos[0], "--checkpoint", path, "-o", tmp_path / "maps")
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1, result.stderr


def test_unknown_run_id(tmp_path, photos):
    """--run with an id the store does not have: a one-line error naming the run, exit 2, nothing written."""
    run_id = "0123456789abcdef0123456789abcdef"
    result = run_cli("predict", str(photos[0]), "--run", run_id, "-o", str(tmp_path / "maps"))
    assert result.returncode == 2
    assert result.stderr.startswith("svbrdf-train: error: ") and result.stderr.count("\n") == 1
    assert run_id in result.stderr and "MLFLOW_TRACKING_URI" in result.stderr
    assert not (tmp_path / "maps").exists()


def test_without_a_model_the_shipped_one_is_used_and_named(tmp_path, photos):
    """No --model, --checkpoint or --run: the model inside svbrdf-models predicts, and stderr says
    which and where its card is; the maps are the shipped model's own."""
    import svbrdf_models as sm
    from svbrdf_models.modelfile.files import card_path

    out = tmp_path / "maps"
    result = run_cli("predict", str(photos[0]), "-o", str(out), "--relit", "none")
    assert result.returncode == 0, result.stderr
    assert "using the model shipped with svbrdf-models" in result.stderr and str(card_path()) in result.stderr
    model = sm.load_model("pretrained")
    assert json.loads((out / "summary.json").read_text())["model"] == model.source
    stored = _read_maps(out / photos[0].stem)
    want = _encoded(model.predict(srgb_to_linear(read_image(photos[0]))))
    for name in MAPS:
        assert _max_diff(stored[name], want[name]) <= EIGHT_BIT, name
