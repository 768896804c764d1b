"""Bad inputs and faults across the four command lines, as a careful adversarial user meets them.

One table: each row runs a command (in-process, so the table stays fast) on a damaged file, an
unwritable output, a full disk or a bad value, and the test asserts what every row must show:

- the exit status the command's ``--help`` documents (2: refused before any work; 3: a file
  could not be written), never a traceback or a crash;
- one error line, naming the input the user gave (not an internal temporary file);
- no temporary file left behind, and no file half-written.

A full disk is a file-size limit here (``RLIMIT_FSIZE``: a write past it fails with EFBIG, as
one past a full disk fails with ENOSPC; both go through the same code). Where the test may
mount a small tmpfs (a user namespace, ``unshare -rm``), :func:`test_a_real_full_disk` runs the
same commands on one, in a child process.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from conftest import des18_strips, run_cli
from svbrdf_render import write_image
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_train.data import ProceduralMaterials
from svbrdf_train.training.checkpoint import load_checkpoint, save_checkpoint

SMOKE = ("--recipe", "ours", "--size", "smoke", "-q", "--no-track")


# -- the damaged and hostile files the table uses ----------------------------------------------


class _Evil:
    """A pickle that runs a command when loaded (what a hostile checkpoint would hold)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Good inputs, and damaged copies of each, made once for the whole table."""
    root = tmp_path_factory.mktemp("inputs")
    fit = root / "fit"
    done = run_cli("fit", *SMOKE, "--out", str(fit))
    assert done.returncode == 0, done.stderr
    good = fit / "last.pt"
    state = load_checkpoint(good)
    out: dict[str, Path] = {"ckpt": good, "fit": fit}

    nan = {**state, "generator": dict(state["generator"])}
    first = next(iter(nan["generator"]))
    nan["generator"][first] = torch.full_like(nan["generator"][first], float("nan"))
    out["nan_ckpt"] = save_checkpoint(root / "nan" / "last.pt", {k: v for k, v in nan.items() if k != "format"})

    other = {k: v for k, v in state.items() if k != "format"}
    weights = dict(state["generator"])
    for key in list(weights)[:3]:
        weights[key + "_renamed"] = weights.pop(key)
    other["generator"] = weights
    out["other_ckpt"] = save_checkpoint(root / "other" / "last.pt", other)

    out["evil_marker"] = root / "pwned"
    torch.save({"format": 1, "payload": _Evil(out["evil_marker"])}, root / "evil.pt")
    out["evil_ckpt"] = root / "evil.pt"

    raw = good.read_bytes()
    (root / "truncated.pt").write_bytes(raw[: len(raw) // 2])
    out["truncated_ckpt"] = root / "truncated.pt"

    shard = root / "test.h5"
    done = run_cli("data", "make", "--count", "4", "--resolution", "32", "--out", str(shard))
    assert done.returncode == 0, done.stderr
    out["shard"] = shard
    blob = shard.read_bytes()
    (root / "truncated.h5").write_bytes(blob[: len(blob) // 2])
    out["truncated_shard"] = root / "truncated.h5"
    corrupt = bytearray(blob)
    for i in range(len(blob) // 2, len(blob) // 2 + 4096):  # inside the samples' chunks
        corrupt[i] ^= 0xFF
    (root / "corrupt.h5").write_bytes(bytes(corrupt))
    out["corrupt_shard"] = root / "corrupt.h5"
    (root / "text.h5").write_text("not an HDF5 file\n")
    out["text_shard"] = root / "text.h5"

    photo = ProceduralMaterials(1, 96, seed=3)[0]["input"]
    out["photo"] = write_image(root / "photo.png", linear_to_srgb(photo))
    png = out["photo"].read_bytes()
    (root / "cut.png").write_bytes(png[: len(png) // 3])
    out["cut_photo"] = root / "cut.png"

    out["des18"] = des18_strips(root / "des18", count=2, size=64)
    strip = next(out["des18"].glob("*.png"))
    (root / "cut-strip.png").write_bytes(strip.read_bytes()[:400])
    out["cut_strip"] = root / "cut-strip.png"
    (root / "notes").mkdir()
    (root / "notes" / "a.txt").write_text("nothing here\n")
    out["text_folder"] = root / "notes"

    (root / "broken.yaml").write_text("name: x\ngenerator: [unclosed\n")
    out["broken_yaml"] = root / "broken.yaml"
    (root / "scene.yaml").write_text("camera: {position: [0, 0, 0\n")
    out["broken_scene"] = root / "scene.yaml"
    (root / "a-file").write_text("a file where a folder should be\n")
    out["in_the_way"] = root / "a-file"

    # recipes, checkpoints and resume (issue 27): damaged checkpoint headers, hostile recipe files
    damaged = {
        "no_recipe": {"recipe": None},  # None: the field is left out
        "empty_optimizers": {"optimizers": {}},
        "recipe_list": {"recipe": [1, 2]},
        "rng_garbage": {"rng": [{"torch": torch.zeros(3, dtype=torch.uint8)}]},
        "step_string": {"step": "ten"},
        "step_negative": {"step": -5},
        "step_beyond": {"step": 10**6},
        "time_nan": {"train_seconds": float("nan")},
    }
    for name, change in damaged.items():
        broken = {**state, **change}
        broken = {k: v for k, v in broken.items() if not (k in change and v is None)}
        (root / name).mkdir()
        torch.save(broken, root / name / "last.pt")  # as written, not through save_checkpoint's checks
        out[f"resume_{name}"] = root / name
    out["deep_recipe"] = root / "deep.yaml"
    out["deep_recipe"].write_text("base: ours\ngenerator: {name: ours, config: " + "{a: " * 3000 + "1" + "}" * 3001 + "\n")
    out["latin1_recipe"] = root / "latin1.yaml"
    out["latin1_recipe"].write_bytes("description: caf\xe9\nbase: ours\n".encode("latin-1"))
    bomb = "base: ours\ndescription:\n  - &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n"
    for i in range(1, 9):  # 9**9 strings once expanded: the description is printed and logged
        bomb += f"  - &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    out["alias_bomb"] = root / "bomb.yaml"
    out["alias_bomb"].write_text(bomb)
    out["duplicate_recipe"] = root / "twice.yaml"
    out["duplicate_recipe"].write_text("base: ours\ntrain:\n  epochs: 2\n  epochs: 3\n")
    out["duplicate_scene"] = root / "twice-scene.yaml"
    out["duplicate_scene"].write_text("camera: {position: [0, 0, 2.5]}\ncamera: {position: [0, 0, 3]}\n")

    # model files and model URLs (issue 27): headers of the wrong type or range, absurd
    # networks, a stale .sha256 sidecar, a zip that expands far beyond its size
    import zipfile

    from svbrdf_models import create_generator
    from svbrdf_models.modelfile.files import model_dict, save_model

    model = model_dict("ours", {"preset": "tiny"}, create_generator("ours", preset="tiny").state_dict(),
                       resolution=32, provenance={"steps": 1})  # fmt: skip
    config = model["generator"]["config"]
    headers = {
        "config_list": {"generator": {"name": "ours", "config": [1, 2]}},
        "name_list": {"generator": {"name": ["ours"], "config": config}},
        "metrics_str": {"metrics": "0.1"},
        "provenance_list": {"provenance": [1, 2]},
        "steps_str": {"provenance": {"steps": "7"}},
        "resolution_str": {"resolution": "32"},
        "resolution_nan": {"resolution": float("nan")},
        "resolution_zero": {"resolution": 0},
        "resolution_negative": {"resolution": -32},
        "resolution_huge": {"resolution": 10**9},
        "weights_list": {"weights": [torch.zeros(2)]},
        "weights_tensor": {"weights": torch.zeros(2)},
        "depth_huge": {"generator": {"name": "ours", "config": {**config, "depth": 100_000}}},
        "channels_huge": {"generator": {"name": "ours", "config": {**config, "base_channels": 10**6, "max_channels": 10**6}}},
    }
    for name, change in headers.items():
        out[f"model_{name}"] = root / f"model-{name}.pt"
        torch.save({**model, **change}, out[f"model_{name}"])
    out["model_stale"] = root / "model-stale.pt"
    save_model(out["model_stale"], model)
    (root / "model-stale.pt.sha256").write_text("0" * 64 + "  model-stale.pt\n")  # not its SHA-256
    packed = io.BytesIO()
    torch.save({**model, "recipe": {"blob": torch.zeros(2**22)}}, packed)  # 16 MiB of zeros
    out["model_bomb"] = root / "model-bomb.pt"
    with zipfile.ZipFile(packed) as src, zipfile.ZipFile(out["model_bomb"], "w", zipfile.ZIP_DEFLATED) as dst:
        for entry in src.infolist():
            dst.writestr(entry.filename, src.read(entry.filename))
    return out


# -- running a command in-process --------------------------------------------------------------


@contextlib.contextmanager
def _file_size_limit(nbytes: int | None):
    """Writes past ``nbytes`` in one file fail with EFBIG (Python ignores SIGXFSZ)."""
    if nbytes is None:
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


def _argparse_main(main, argv) -> tuple[int, str]:
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as e:  # argparse's usage errors
            code = e.code if isinstance(e.code, int) else 2
    return code, err.getvalue()


def invoke(prog: str, argv: list[str], limit: int | None = None) -> tuple[int, str]:
    """Run ``prog argv`` in this process: (exit status, stderr). A traceback fails the test."""
    with _file_size_limit(limit):
        if prog == "svbrdf-render":
            from svbrdf_render.cli import main

            return _argparse_main(main, argv)
        if prog == "svbrdf-models":
            from svbrdf_models.cli import main

            return _argparse_main(main, argv)
        if prog == "svbrdf-train":
            from svbrdf_train.cli import cli
        else:
            from svbrdf_bench.cli import cli
        result = CliRunner().invoke(cli, argv, prog_name=prog)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception  # what a user would see as a traceback
    return result.exit_code, result.stderr


# -- the table ----------------------------------------------------------------------------------

# (id, prog, argv with {placeholders}, file-size limit, exit status, what the message must name)
# {tmp} is the test's own folder; other {names} are the files of the `files` fixture.
CASES = [
    # damaged, foreign and hostile checkpoints
    ("predict-nan-weights", "svbrdf-train", "predict {photo} --checkpoint {nan_ckpt} -o {tmp}/maps", None, 2, "{nan_ckpt}"),
    ("predict-evil-pickle", "svbrdf-train", "predict {photo} --checkpoint {evil_ckpt} -o {tmp}/maps", None, 2, "{evil_ckpt}"),
    ("predict-truncated-ckpt", "svbrdf-train", "predict {photo} --checkpoint {truncated_ckpt} -o {tmp}/maps", None, 2, "{truncated_ckpt}"),
    ("predict-other-generator", "svbrdf-train", "predict {photo} --checkpoint {other_ckpt} -o {tmp}/maps", None, 2, "{other_ckpt}"),
    ("predict-missing-ckpt", "svbrdf-train", "predict {photo} --checkpoint {tmp}/none.pt -o {tmp}/maps", None, 2, "{tmp}/none.pt"),
    ("predict-ckpt-is-folder", "svbrdf-train", "predict {photo} --checkpoint {tmp} -o {tmp}/maps", None, 2, "{tmp}"),
    ("init-nan-weights", "svbrdf-train", "fit {smoke} --init {nan_ckpt} --out {tmp}/run", None, 2, "{nan_ckpt}"),
    ("init-evil-pickle", "svbrdf-train", "fit {smoke} --init {evil_ckpt} --out {tmp}/run", None, 2, "{evil_ckpt}"),
    ("init-truncated", "svbrdf-train", "fit {smoke} --init {truncated_ckpt} --out {tmp}/run", None, 2, "{truncated_ckpt}"),
    ("init-other-generator", "svbrdf-train", "fit {smoke} --init {other_ckpt} --out {tmp}/run", None, 2, "{other_ckpt}"),
    ("init-nothing", "svbrdf-train", "fit {smoke} --init {tmp}/nothing --out {tmp}/run", None, 2, "{tmp}/nothing"),
    ("resume-nothing", "svbrdf-train", "fit --resume --out {tmp}/never", None, 2, "{tmp}/never"),
    # damaged data
    ("fit-truncated-shard", "svbrdf-train", "fit {smoke} --data {truncated_shard} --out {tmp}/run", None, 2, "{truncated_shard}"),
    ("fit-text-as-shard", "svbrdf-train", "fit {smoke} --data {text_shard} --out {tmp}/run", None, 2, "{text_shard}"),
    ("fit-missing-data", "svbrdf-train", "fit {smoke} --data {tmp}/none.h5 --out {tmp}/run", None, 2, "{tmp}/none.h5"),
    ("fit-text-folder", "svbrdf-train", "fit {smoke} --data {text_folder} --out {tmp}/run", None, 2, "{text_folder}"),
    ("import-text-folder", "svbrdf-train", "data import {text_folder} --out {tmp}/x.h5", None, 2, "{text_folder}"),
    ("import-missing", "svbrdf-train", "data import {tmp}/none --out {tmp}/x.h5", None, 2, "{tmp}/none"),
    ("predict-cut-photo", "svbrdf-train", "predict {cut_photo} --checkpoint {ckpt} -o {tmp}/maps", None, 2, "{cut_photo}"),
    ("predict-missing-photo", "svbrdf-train", "predict {tmp}/none.jpg --checkpoint {ckpt} -o {tmp}/maps", None, 2, "{tmp}/none.jpg"),
    ("render-cut-strip", "svbrdf-render", "render {cut_strip} -o {tmp}/x.png", None, 2, "{cut_strip}"),
    ("render-missing", "svbrdf-render", "render {tmp}/none.png -o {tmp}/x.png", None, 2, "{tmp}/none.png"),
    ("render-broken-scene", "svbrdf-render", "render example:tiles --scene {broken_scene} -o {tmp}/x.png", None, 2, "{broken_scene}"),
    ("render-missing-scene", "svbrdf-render", "render example:tiles --scene {tmp}/none.yaml -o {tmp}/x.png", None, 2, "{tmp}/none.yaml"),
    ("recipe-broken-yaml", "svbrdf-train", "fit --recipe {broken_yaml} --size smoke --out {tmp}/run", None, 2, "{broken_yaml}"),
    ("recipes-broken-yaml", "svbrdf-train", "recipes {broken_yaml}", None, 2, "{broken_yaml}"),
    ("recipe-missing", "svbrdf-train", "fit --recipe {tmp}/none.yaml --size smoke --out {tmp}/run", None, 2, "none.yaml"),
    ("bench-corrupt-test-shard", "svbrdf-bench", "run --models ours --size smoke --test-data {corrupt_shard} -o {tmp}/bench", None, 2, "{corrupt_shard}"),
    ("bench-truncated-test-shard", "svbrdf-bench", "run --models ours --size smoke --test-data {truncated_shard} -o {tmp}/bench", None, 2, "{truncated_shard}"),
    ("bench-test-text-folder", "svbrdf-bench", "run --models ours --size smoke --test-data {text_folder} -o {tmp}/bench", None, 2, "{text_folder}"),
    # outputs that cannot be written: a file where a folder must be
    ("render-out-blocked", "svbrdf-render", "render example:tiles --size 32 -o {in_the_way}/x.png", None, 2, "{in_the_way}/x.png"),
    ("scene-out-blocked", "svbrdf-render", "scene -o {in_the_way}/s.yaml", None, 2, "{in_the_way}/s.yaml"),
    ("make-out-blocked", "svbrdf-train", "data make --count 2 --resolution 32 --out {in_the_way}/x.h5", None, 2, "{in_the_way}/x.h5"),
    ("sheet-out-blocked", "svbrdf-train", "data sheet -n 2 -o {in_the_way}/s.png", None, 2, "{in_the_way}/s.png"),
    ("fit-out-blocked", "svbrdf-train", "fit {smoke} --out {in_the_way}/run", None, 2, "{in_the_way}/run"),
    ("predict-out-blocked", "svbrdf-train", "predict {photo} --checkpoint {ckpt} -o {in_the_way}/maps", None, 2, "{in_the_way}/maps"),
    ("bench-out-blocked", "svbrdf-bench", "run --models ours --size smoke -o {in_the_way}/bench", None, 2, "{in_the_way}/bench"),
    ("bench-render-out-blocked", "svbrdf-bench", "render --quick --no-track --out {in_the_way}/r", None, 2, "{in_the_way}/r"),
    # a full disk (a file-size limit): exit 3, the file named, nothing half-written
    ("make-disk-full", "svbrdf-train", "data make --count 40 --resolution 64 --out {tmp}/x.h5", 200_000, 3, "{tmp}/x.h5"),
    ("import-disk-full", "svbrdf-train", "data import {des18} --full --out {tmp}/x.h5", 20_000, 3, "{tmp}/x.h5"),
    ("sheet-disk-full", "svbrdf-train", "data sheet -n 4 -o {tmp}/s.png", 2_000, 3, "{tmp}/s.png"),
    ("fit-checkpoint-disk-full", "svbrdf-train", "fit {smoke} --out {tmp}/run", 400_000, 3, "{tmp}/run/last.pt"),
    ("predict-disk-full", "svbrdf-train", "predict {photo} --checkpoint {ckpt} -o {tmp}/maps", 1_000, 3, "{tmp}/maps"),
    ("render-disk-full", "svbrdf-render", "render example:tiles --size 64 -o {tmp}/x.png", 1_000, 3, "{tmp}/x.png"),
    ("preview-disk-full", "svbrdf-render", "preview example:tiles --size 32 --grid 2 -o {tmp}/x.png", 1_000, 3, "{tmp}/x.png"),
    ("scene-disk-full", "svbrdf-render", "scene -o {tmp}/s.yaml", 10, 3, "{tmp}/s.yaml"),
    # bad values and flags
    ("models-unknown", "svbrdf-models", "describe no-such-model", None, 2, "no-such-model"),
    ("render-unknown-example", "svbrdf-render", "render example:nope -o {tmp}/x.png", None, 2, "nope"),
    ("render-unknown-effect", "svbrdf-render", "render example:tiles --effects glow -o {tmp}/x.png", None, 2, "glow"),
    ("fit-unknown-recipe", "svbrdf-train", "fit --recipe no-such-recipe --size smoke --out {tmp}/run", None, 2, "no-such-recipe"),
    ("fit-bad-set", "svbrdf-train", "fit {smoke} --set nosection --out {tmp}/run", None, 2, "nosection"),
    ("fit-unknown-field", "svbrdf-train", "fit {smoke} --set train.nofield=1 --out {tmp}/run", None, 2, "nofield"),
    ("fit-init-and-resume", "svbrdf-train", "fit {smoke} --init {ckpt} --resume --out {tmp}/run", None, 2, "--init"),
    ("fit-checkpoint-there", "svbrdf-train", "fit {smoke} --out {fit}", None, 2, "{fit}"),
    ("predict-bad-crop", "svbrdf-train", "predict {photo} --checkpoint {ckpt} --crop 1,2 -o {tmp}/maps", None, 2, "1,2"),
    ("predict-two-models", "svbrdf-train", "predict {photo} --model pretrained --checkpoint {ckpt} -o {tmp}/maps", None, 2, "--model"),
    ("predict-model-missing", "svbrdf-train", "predict {photo} --model {tmp}/none.pt -o {tmp}/maps", None, 2, "{tmp}/none.pt"),
    ("predict-model-is-photo", "svbrdf-train", "predict {photo} --model {photo} -o {tmp}/maps", None, 2, "{photo}"),
    ("models-show-missing", "svbrdf-models", "show {tmp}/none.pt", None, 2, "{tmp}/none.pt"),
    ("models-predict-refine-negative", "svbrdf-models", "predict {photo} --refine -1 -o {tmp}/maps", None, 2, "--refine"),
    ("models-predict-refine-word", "svbrdf-models", "predict {photo} --refine all -o {tmp}/maps", None, 2, "--refine"),
    ("models-predict-map-size-tiny", "svbrdf-models", "predict {photo} --refine 2 --map-size 8 -o {tmp}/maps", None, 2, "--map-size"),
    ("models-predict-cut-photo", "svbrdf-models", "predict {cut_photo} --refine 0 -o {tmp}/maps", None, 2, "{cut_photo}"),
    ("models-predict-scene-missing", "svbrdf-models", "predict {photo} --scene {tmp}/none.yaml -o {tmp}/maps", None, 2, "{tmp}/none.yaml"),
    ("models-predict-disk-full", "svbrdf-models", "predict {photo} --refine 0 -o {tmp}/maps", 1_000, 3, "{tmp}/maps"),
    ("bench-unknown-model", "svbrdf-bench", "run --models no-such-recipe -o {tmp}/bench", None, 2, "no-such-recipe"),
    ("bench-no-models", "svbrdf-bench", "run -o {tmp}/bench", None, 2, "--models"),
    ("bench-unknown-report", "svbrdf-bench", "report 0123456789abcdef0123456789abcdef", None, 2, "0123456789abcdef0123456789abcdef"),
    ("fit-real-validation-missing", "svbrdf-train", "fit {smoke} --set data.real_validation={tmp}/none --out {tmp}/run", None, 2, "{tmp}/none"),
    ("fit-resolution-not-multiple", "svbrdf-train", "fit {smoke} --set train.resolution=30 --out {tmp}/run", None, 2, "train.resolution"),
    ("fit-lr-zero", "svbrdf-train", "fit {smoke} --set optim.lr=0 --out {tmp}/run", None, 2, "lr"),
    ("fit-max-steps-zero", "svbrdf-train", "fit {smoke} --max-steps 0 --out {tmp}/run", None, 2, "--max-steps"),
    ("render-distance-zero", "svbrdf-render", "render example:tiles --distance 0 -o {tmp}/x.png", None, 2, "--distance"),
    ("render-size-negative", "svbrdf-render", "render example:tiles --size -3 -o {tmp}/x.png", None, 2, "--size"),
    ("render-size-huge", "svbrdf-render", "render example:tiles --size 100000 -o {tmp}/x.png", None, 2, "--size"),
    ("models-channels-huge", "svbrdf-models", "list --kind attention --pattern multiscale --detail --channels 100000", None, 2, "--channels"),
    # outputs that hold work (issue 27, export): a model file never replaces a checkpoint or another file
    ("export-over-checkpoint", "svbrdf-train", "export {fit} -o {other_ckpt}", None, 2, "-o {other_ckpt}: a training checkpoint is there"),
    ("export-over-other-file", "svbrdf-train", "export {fit} -o {broken_yaml}", None, 2, "-o {broken_yaml}: a file that is not a model file"),
    # recipes, checkpoints and resume (issue 27): one line naming the file and the field or key
    ("resume-no-recipe", "svbrdf-train", "fit --resume -q --no-track --out {resume_no_recipe}", None, 2, "{resume_no_recipe}/last.pt: no 'recipe'"),
    ("resume-empty-optimizers", "svbrdf-train", "fit --resume -q --no-track --out {resume_empty_optimizers}", None, 2, "{resume_empty_optimizers}/last.pt: field 'optimizers'"),
    ("resume-recipe-list", "svbrdf-train", "fit --resume -q --no-track --out {resume_recipe_list}", None, 2, "{resume_recipe_list}/last.pt: field 'recipe'"),
    ("resume-rng-garbage", "svbrdf-train", "fit --resume -q --no-track --out {resume_rng_garbage}", None, 2, "{resume_rng_garbage}/last.pt: field 'rng[0].torch'"),
    ("resume-step-string", "svbrdf-train", "fit --resume -q --no-track --out {resume_step_string}", None, 2, "{resume_step_string}/last.pt: field 'step'"),
    ("resume-step-negative", "svbrdf-train", "fit --resume -q --no-track --out {resume_step_negative}", None, 2, "{resume_step_negative}/last.pt: field 'step'"),
    ("resume-step-beyond-budget", "svbrdf-train", "fit --resume -q --no-track --out {resume_step_beyond}", None, 2, "{resume_step_beyond}/last.pt: its step 1000000 is beyond the budget"),
    ("resume-time-nan", "svbrdf-train", "fit --resume -q --no-track --out {resume_time_nan}", None, 2, "{resume_time_nan}/last.pt: field 'train_seconds'"),
    ("resume-recipe-list-with-recipe", "svbrdf-train", "fit {smoke} --resume --out {resume_recipe_list}", None, 2, "{resume_recipe_list}/last.pt: field 'recipe'"),
    ("recipe-nested-deep", "svbrdf-train", "fit --recipe {deep_recipe} --size smoke --out {tmp}/run", None, 2, "{deep_recipe}: not valid YAML: nested deeper"),
    ("recipe-not-utf8", "svbrdf-train", "fit --recipe {latin1_recipe} --size smoke --out {tmp}/run", None, 2, "{latin1_recipe}: not UTF-8"),
    ("recipe-alias-bomb", "svbrdf-train", "recipes {alias_bomb}", None, 2, "{alias_bomb}: not valid YAML: aliases expand"),
    ("recipe-duplicate-key", "svbrdf-train", "fit --recipe {duplicate_recipe} --size smoke --out {tmp}/run", None, 2, "{duplicate_recipe}: not valid YAML: duplicate key 'epochs'"),
    ("scene-duplicate-key", "svbrdf-render", "render example:tiles --size 32 --scene {duplicate_scene} -o {tmp}/x.png", None, 2, "{duplicate_scene}: not valid YAML (duplicate key 'camera'"),
    ("fit-set-twice", "svbrdf-train", "fit {smoke} --set train.epochs=2 --set train.epochs=3 --out {tmp}/run", None, 2, "--set train.epochs is given twice"),
    ("fit-max-steps-and-set", "svbrdf-train", "fit {smoke} --max-steps 3 --set train.max_steps=4 --out {tmp}/run", None, 2, "train.max_steps"),
    ("fit-data-and-set-path", "svbrdf-train", "fit {smoke} --data procedural --set data.source=des18 --out {tmp}/run", None, 2, "--data and --set data.source"),
    ("bench-test-data-twice", "svbrdf-bench", "run --models ours --size smoke --test-data {shard} --test-data {des18} -o {tmp}/bench", None, 2, "--test-data is given 2 times"),
    # model files and model URLs (issue 27): one line naming the file and the field, exit 2
    ("models-show-config-list", "svbrdf-models", "show {model_config_list}", None, 2, "{model_config_list}: damaged model file: field 'generator.config'"),
    ("models-show-name-list", "svbrdf-models", "show {model_name_list}", None, 2, "{model_name_list}: damaged model file: field 'generator.name'"),
    ("models-show-metrics-str", "svbrdf-models", "show {model_metrics_str}", None, 2, "{model_metrics_str}: damaged model file: field 'metrics'"),
    ("models-show-provenance-list", "svbrdf-models", "show {model_provenance_list}", None, 2, "{model_provenance_list}: damaged model file: field 'provenance'"),
    ("models-show-steps-str", "svbrdf-models", "show {model_steps_str}", None, 2, "{model_steps_str}: damaged model file: field 'provenance.steps'"),
    ("models-show-resolution-str", "svbrdf-models", "show {model_resolution_str}", None, 2, "{model_resolution_str}: damaged model file: field 'resolution'"),
    ("models-show-resolution-nan", "svbrdf-models", "show {model_resolution_nan}", None, 2, "{model_resolution_nan}: damaged model file: field 'resolution'"),
    ("models-show-resolution-zero", "svbrdf-models", "show {model_resolution_zero}", None, 2, "{model_resolution_zero}: damaged model file: field 'resolution'"),
    ("models-show-resolution-negative", "svbrdf-models", "show {model_resolution_negative}", None, 2, "{model_resolution_negative}: damaged model file: field 'resolution'"),
    ("models-show-resolution-huge", "svbrdf-models", "show {model_resolution_huge}", None, 2, "{model_resolution_huge}: damaged model file: field 'resolution'"),
    ("models-show-weights-list", "svbrdf-models", "show {model_weights_list}", None, 2, "{model_weights_list}: damaged model file: field 'weights'"),
    ("models-show-weights-tensor", "svbrdf-models", "show {model_weights_tensor}", None, 2, "{model_weights_tensor}: damaged model file: field 'weights'"),
    ("models-show-depth-huge", "svbrdf-models", "show {model_depth_huge}", None, 2, "depth must be from 2 to 13"),
    ("models-show-channels-huge", "svbrdf-models", "show {model_channels_huge}", None, 2, "million parameters, over the 500 million"),
    ("fit-set-depth-huge", "svbrdf-train", "fit {smoke} --set generator.config.depth=1000000000 --out {tmp}/run", None, 2, "depth must be from 2 to 13"),
    ("fit-set-disc-layers-huge", "svbrdf-train", "fit {smoke} --set discriminator.config.layers=100000 --out {tmp}/run", None, 2, "layers must be at most 11"),
    ("fit-set-disc-channels-huge", "svbrdf-train", "fit {smoke} --set discriminator.config.base_channels=100000 --out {tmp}/run", None, 2, "million parameters, over the 500 million a discriminator"),
    ("fit-set-channels-huge", "svbrdf-train", "fit {smoke} --set generator.config.base_channels=100000 --set generator.config.max_channels=100000 --out {tmp}/run", None, 2, "million parameters, over the 500 million"),
    ("models-show-stale-sidecar", "svbrdf-models", "show {model_stale}", None, 2, "{model_stale}: its SHA-256 is"),
    ("models-predict-stale-sidecar", "svbrdf-models", "predict {photo} --model {model_stale} --refine 0 -o {tmp}/maps", None, 2, "{model_stale}: its SHA-256 is"),
    ("models-show-zip-bomb", "svbrdf-models", "show {model_bomb}", None, 2, "{model_bomb}: it would expand to"),
]


def _fill(text: str, files: dict[str, Path], tmp: Path) -> str:
    names = {k: str(v) for k, v in files.items()}
    return text.format(tmp=tmp, smoke=" ".join(SMOKE), **names)


def _leftovers(*folders: Path) -> list[Path]:
    return [p for folder in folders for p in folder.rglob(".*.tmp")]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_or_fault_is_one_line_with_the_documented_status(case, files, tmp_path, monkeypatch):
    _, prog, argv, limit, status, named = case
    monkeypatch.chdir(tmp_path)  # anything written by default lands in the test's own folder
    args = _fill(argv, files, tmp_path).split()
    code, stderr = invoke(prog, args, limit)
    assert "Traceback" not in stderr
    errors = [line for line in stderr.splitlines() if "error:" in line.lower()]
    assert len(errors) == 1, stderr
    assert code == status, stderr
    assert _fill(named, files, tmp_path) in errors[0], errors[0]
    assert "weights_only=False" not in stderr  # never advise unpickling an untrusted file
    assert not _leftovers(tmp_path, files["fit"].parent), "a temporary file was left behind"
    assert not files["evil_marker"].exists(), "a hostile checkpoint ran code"


def test_the_table_covers_sixty_inputs_across_the_four_command_lines():
    assert len(CASES) >= 60
    assert {c[1] for c in CASES} == {"svbrdf-render", "svbrdf-models", "svbrdf-train", "svbrdf-bench"}


# -- what a failed write leaves ----------------------------------------------------------------


def test_a_failed_shard_write_keeps_the_previous_shard(files, tmp_path):
    target = tmp_path / "x.h5"
    shutil.copyfile(files["shard"], target)
    before = target.read_bytes()
    code, stderr = invoke(
        "svbrdf-train", ["data", "make", "--count", "40", "--resolution", "64", "--out", str(target), "--force"], 200_000
    )
    assert code == 3, stderr
    assert target.read_bytes() == before
    assert not _leftovers(tmp_path)


def test_a_failed_predict_leaves_no_empty_summary(files, tmp_path):
    out = tmp_path / "maps"
    code, stderr = invoke(
        "svbrdf-train", ["predict", str(files["photo"]), "--checkpoint", str(files["ckpt"]), "-o", str(out)], 1_000
    )
    assert code == 3, stderr
    summary = out / "summary.json"
    assert not summary.exists() or json.loads(summary.read_text())["photos"] == 1
    assert all(p.stat().st_size > 0 for p in out.rglob("*") if p.is_file())


# -- a real full disk, and a read-only one ------------------------------------------------------


def _can_mount() -> bool:
    if not shutil.which("unshare") or sys.platform != "linux":
        return False
    probe = subprocess.run(
        ["unshare", "-rm", "sh", "-c", "d=$(mktemp -d) && mount -t tmpfs -o size=1m tmpfs $d && umount $d"],
        capture_output=True,
    )
    return probe.returncode == 0


def _on_small_disk(size: str, script: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """Run ``script`` (bash) with ``$DISK`` a fresh tmpfs of ``size``; ``$PY`` is this Python."""
    mount = f'DISK=$(mktemp -d) && mount -t tmpfs -o size={size} tmpfs "$DISK" && export DISK && {script}'
    return subprocess.run(
        ["unshare", "-rm", "bash", "-c", mount],
        cwd=cwd,
        env={**os.environ, "PY": sys.executable, **env},
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow
@pytest.mark.skipif(not _can_mount(), reason="cannot mount a tmpfs here (no user namespaces)")
def test_a_real_full_disk(files, tmp_path):
    """ENOSPC on a 3 MiB tmpfs: a shard, a fit's second checkpoint, a read-only MLflow store.

    Each ends with one line and exit 3; the fit keeps its first checkpoint whole and resumable.
    """
    script = r"""
    report() { echo "== $1 rc=$2 left=$(find "$DISK" -name '.*.tmp' | wc -l)"; }
    $PY -m svbrdf_train data make --count 200 --resolution 64 --out "$DISK/x.h5" 2>/dev/null
    report make $?
    rm -f "$DISK/x.h5"
    $PY -m svbrdf_train fit --recipe ours --size smoke -q --no-track --max-steps 4 \
        --set train.checkpoint_every=1 --out "$DISK/run" 2>/dev/null
    report fit $?
    $PY -c "from svbrdf_train.training.checkpoint import load_checkpoint as l; print('== kept step', l('$DISK/run/last.pt')['step'])"
    """
    done = _on_small_disk("3m", script, tmp_path)
    lines = [line for line in done.stdout.splitlines() if line.startswith("==")]
    assert lines[0] == "== make rc=3 left=0", done.stdout + done.stderr
    assert lines[1] == "== fit rc=3 left=0", done.stdout + done.stderr
    assert lines[2] == "== kept step 1", done.stdout + done.stderr


@pytest.mark.slow
@pytest.mark.skipif(not _can_mount(), reason="cannot mount a tmpfs here (no user namespaces)")
def test_a_read_only_mlflow_store_is_one_line_before_training(files, tmp_path):
    script = r"""
    cp "$STORE" "$DISK/mlflow.db" && mount -o remount,ro "$DISK"
    MLFLOW_TRACKING_URI="sqlite:///$DISK/mlflow.db" $PY -m svbrdf_train fit --recipe ours --size smoke -q \
        --out run 2>err.txt
    echo "== rc=$?"
    """
    store = tmp_path / "store.db"
    made = run_cli("fit", "--recipe", "ours", "--size", "smoke", "-q", "--out", "r0", cwd=tmp_path,
                   env={"MLFLOW_TRACKING_URI": f"sqlite:///{store}"})  # fmt: skip
    assert made.returncode == 0, made.stderr
    done = _on_small_disk("20m", script, tmp_path, STORE=str(store))
    assert "== rc=3" in done.stdout, done.stdout + done.stderr
    err = (tmp_path / "err.txt").read_text()
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "mlflow.db" in err and "writable" in err
    assert not (tmp_path / "run" / "last.pt").exists()  # refused before training
