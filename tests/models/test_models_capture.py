"""The photo tool in svbrdf-models: ``TrainedModel.predict(photo, refine=STEPS)`` and
``svbrdf-models predict`` (network, then refinement against the photo).

Photos are made here: known maps rendered under a known flash, saved as sRGB PNG. The model is
the one shipped with the package (128 px); refinements are a few eager steps on small photos.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models import capture
from svbrdf_models.capture.photos import square_photo
from svbrdf_models.capture.refining import rerender, rerender_rmse
from svbrdf_models.cli import main
from svbrdf_models.errors import DataError
from svbrdf_render import (
    DEFAULT_REFINE_STEPS,
    MIN_REFINE_SIDE,
    Camera,
    PointLight,
    Scene,
    read_image,
    render,
    write_image,
)
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.plumbing import ProgressBar, machine

MAPS = ("normal", "diffuse", "roughness", "specular")
#: The material folder's files besides the four maps and the figures (svbrdf_models.capture.material).
MATERIAL = {"basecolor.png", "metallic.png", "metallic_roughness.png", "material.json", "material.gltf",
            "material.mtlx", "index.html"}  # fmt: skip
SCENE = Scene.flash(intensity=12.0)


@pytest.fixture(scope="module")
def model():
    return sm.load_model("pretrained")


def _photo(size: int = 64, name: str = "tiles", width: int | None = None) -> torch.Tensor:
    """``(3, size, width)`` linear flash photo of a known material (clipped as a camera does)."""
    maps = example_material(name, max(size, width or size))
    photo = render(maps, SCENE).clamp(0, 1)[0]
    return photo[:, :size, : width or size].contiguous()


@pytest.fixture(scope="module")
def photo_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    return write_image(folder / "tiles.png", linear_to_srgb(_photo(72, width=80)))


def _run(*args, capsys=None):
    code = main(["predict", *map(str, args)])
    out = capsys.readouterr() if capsys is not None else None
    return code, out


# -- TrainedModel.predict ----------------------------------------------------------------------


def test_refine_zero_is_the_network_unchanged(model):
    """refine=0 (the default) gives the generator's maps of the centre square at the model's
    resolution, as before refinement existed."""
    photo = _photo(64, width=90)
    with torch.no_grad():
        want = model.generator(square_photo(photo, model.resolution)[None])
    for got in (model.predict(photo), model.predict(photo, 0), model.predict(photo[None], refine=0)):
        assert got.size == (model.resolution, model.resolution)
        for name in MAPS:
            assert torch.equal(getattr(got, name), getattr(want, name)), name


def test_refined_maps_are_photo_sized_and_explain_the_photo_better(model):
    """refine=STEPS: maps at the square's own size (the photo's shorter side), whose re-rendering
    under the refinement's scene is closer to the photo than the network's maps' (brought to
    that size as the refinement's start is)."""
    photo = _photo(64, width=80)
    square = square_photo(photo, None)
    calls = []
    refined = model.predict(photo, 20, scene=SCENE, callback=lambda *a: calls.append(a), backend="eager")
    assert refined.size == (64, 64) and refined.batch_size == 1
    assert [c[0] for c in calls] == list(range(1, 21)) and all(c[1] == 20 for c in calls)
    network = model.predict(photo)
    before = float(rerender_rmse(rerender(network, SCENE, (64, 64)), square)[0])
    after = float(rerender_rmse(rerender(refined, SCENE), square)[0])
    assert after < 0.8 * before, (before, after)
    assert float((refined.normal.norm(dim=1) - 1).abs().max()) < 1e-4


@pytest.mark.parametrize("over", [(0.5, 0.3), (-0.4, -0.35)])
def test_the_flash_is_found_over_the_highlight_of_a_phone_held_off_centre(model, over):
    """A shiny material photographed by a phone held off-centre (camera and flash over
    ``over``): without a given scene, the refinement's flash stands over the highlight. The
    control: the same material photographed from the centre gets the flash at the centre."""
    from svbrdf_models.capture.refining import refine_prediction
    from svbrdf_render import SVBRDF

    maps = SVBRDF.constant(1, 64, diffuse=(0.2, 0.15, 0.1), roughness=0.25, specular=(0.04,) * 3)
    position = torch.tensor([*over, 2.2])
    shifted = render(maps, Scene(Camera(position), (PointLight(position, 12.0),))).clamp(0, 1)
    centred = render(maps, SCENE).clamp(0, 1)
    for photo, want in ((shifted, [*over, 2.2]), (centred, [0.0, 0.0, 2.2])):
        start = model.predict(photo[0])
        result = refine_prediction(photo, start, 2, backend="eager")
        light = result.scene.point_lights[0].position.reshape(-1).tolist()
        assert light == pytest.approx(want, abs=0.1)


def test_refine_runs_under_no_grad_and_inference_mode(model):
    photo = _photo(32)
    with torch.no_grad():
        assert model.predict(photo, 2).size == (32, 32)
    with torch.inference_mode():
        assert model.predict(photo, 2).size == (32, 32)


@pytest.mark.parametrize("refine", [-1, True, 1.5, "3", None])
def test_refine_must_be_a_whole_number_of_steps(model, refine):
    with pytest.raises(DataError, match="refine must be a whole number of refinement steps >= 0") as e:
        model.predict(_photo(32), refine)
    assert "\n" not in str(e.value) and isinstance(e.value, ValueError)


def test_refine_refuses_a_photo_under_the_minimum_side(model):
    small = MIN_REFINE_SIDE - 1
    with pytest.raises(DataError, match=f"smaller than {MIN_REFINE_SIDE} px"):
        model.predict(torch.rand(3, small, 40) * 0.5, 2)
    assert model.predict(torch.rand(3, small, 40) * 0.5).size == (model.resolution,) * 2  # network only


@pytest.mark.slow
def test_refine_at_1024(model):
    """A 1024x1024 photo is refined at its own resolution (two steps: memory and shapes, not quality)."""
    photo = torch.nn.functional.interpolate(_photo(128)[None], size=(1024, 1024), mode="bilinear")[0]
    refined = model.predict(photo, 2)
    assert refined.size == (1024, 1024) and bool(torch.isfinite(refined.pack()).all())


# -- svbrdf-models predict -----------------------------------------------------------------------


def test_command_refines_and_shows_both_versions(tmp_path, photo_file, model, capsys):
    """--refine 4: maps at the square's size (72 of a 72x80 photo), the refined ones; rerender.png
    photo | network | refined | two heat maps; relit.png a row per version for each group of
    angles; summary.json with the budget, steps, seconds and both RMSEs."""
    out = tmp_path / "maps"
    code, got = _run(photo_file, "-o", out, "--refine", 4, "--relit", "png", capsys=capsys)
    assert code == 0, got.err
    assert "using the model shipped with svbrdf-models" in got.err and model.describe() in got.err
    assert got.out.split() == [str(out / "tiles")]
    folder = out / "tiles"
    figures = {f"{n}.png" for n in (*MAPS, "input", "rerender", "relit")}
    assert {p.name for p in folder.iterdir()} == figures | MATERIAL
    assert read_image(folder / "normal.png").shape == (3, 72, 72)
    assert read_image(folder / "input.png").shape == (3, 72, 72)
    figure = read_image(folder / "rerender.png")
    assert figure.shape[2] > 5 * 72 and figure.shape[1] < 2 * 72  # one row of five tiles
    relit = read_image(folder / "relit.png")
    assert relit.shape[1] > 8 * 72 > relit.shape[1] - 8 * 72 - 200  # 2 versions x 4 rows of 6 frames
    summary = json.loads((out / "summary.json").read_text())
    assert summary["refine"] == 4 and summary["model"] == model.source
    entry = summary["entries"][0]
    assert entry["maps"] == 72 and entry["square"] == 72
    r = entry["refine"]
    assert r["budget"] == 4 and r["steps"] == 4 and r["seconds"] > 0 and r["backend"] == "eager"
    assert r["rmse_refined"] == entry["rmse"] and 0 <= r["rmse_refined"] < 1 and 0 <= r["rmse_network"] < 1
    assert "network" in got.err  # the table's column of the network's RMSE


def test_command_writes_the_refined_maps(tmp_path, photo_file):
    """The maps written are the refinement's: the same as TrainedModel.predict with the same
    budget on the same square (within 8-bit steps)."""
    out = tmp_path / "maps"
    assert _run(photo_file, "-o", out, "--refine", 3, "--relit", "none")[0] == 0
    photo, _ = capture.load_photo(photo_file)
    want = sm.load_model("pretrained").predict(photo, 3)
    stored = read_image(out / "tiles" / "diffuse.png")  # sRGB-encoded by default
    assert float((stored - linear_to_srgb(want.diffuse[0])).abs().max()) <= 1 / 255 + 1e-6


def test_command_refine_zero_is_the_network_figure(tmp_path, photo_file, model, capsys):
    """--refine 0: maps at the model's resolution, the flash fitted to them, no refinement entry;
    the gif of the network's maps."""
    out = tmp_path / "maps"
    code, got = _run(photo_file, "-o", out, "--refine", 0, capsys=capsys)
    assert code == 0, got.err
    entry = json.loads((out / "summary.json").read_text())["entries"][0]
    assert entry["maps"] == model.resolution and entry["refine"] is None
    assert "relit.gif" in {p.name for p in (out / "tiles").iterdir()}
    assert read_image(out / "tiles" / "rerender.png").shape[2] < 4 * model.resolution + 200


def test_command_default_budget_is_the_renderers(tmp_path, photo_file, monkeypatch, capsys):
    """No --refine: svbrdf_render.DEFAULT_REFINE_STEPS (read, not copied); --refine-seconds bounds it."""
    out = tmp_path / "maps"
    code, got = _run(photo_file, "-o", out, "--relit", "none", "--refine-seconds", "0.001", capsys=capsys)
    assert code == 0, got.err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["refine"] == DEFAULT_REFINE_STEPS and summary["refine_seconds"] == 0.001
    # the photo's time bound, gone before the steps (reading, the network): no step (issue 47: it
    # bounded the steps alone, and a first step always ran)
    assert summary["entries"][0]["refine"]["steps"] == 0


def _bad_scene(tmp_path):
    """A scene of two light positions: two views, not one photo's capture."""
    scene = Scene(Camera(), (PointLight(torch.tensor([[0.0, 0.0, 2.2], [1.0, 0.0, 2.0]]), 10.0),))
    scene.save(tmp_path / "two-views.yaml")
    return tmp_path / "two-views.yaml"


@pytest.mark.parametrize(
    "args, says",
    [
        (["--refine", "-1"], "--refine: expected an integer at least 0"),
        (["--refine", "many"], "--refine: expected an integer"),
        (["--refine", "2.5"], "--refine: expected an integer"),
        (["--refine-seconds", "0"], "--refine-seconds: expected a finite number > 0"),
        (["--refine", "0", "--refine-seconds", "3"], "--refine-seconds goes with --refine STEPS > 0, not --refine 0"),
        (["--refine", "3", "--map-size", str(MIN_REFINE_SIDE - 1)], f"smaller than {MIN_REFINE_SIDE} px"),
        (["--refine", "0", "--map-size", "64"], "--map-size goes with --tiles or --refine"),
        (["--scene", "TWO_VIEWS"], "the scene has configurations of shape"),
        (["--scene", "MISSING"], "cannot read the scene file"),
        (["--crop", "1,2"], "X,Y,SIZE"),
        (["--device", "tpu"], "--device 'tpu': expected auto, cpu, cuda or cuda:K"),
    ],
)
def test_command_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, photo_file, capsys, args, says):
    args = [str(_bad_scene(tmp_path)) if a == "TWO_VIEWS" else str(tmp_path / "no.yaml") if a == "MISSING"
            else a for a in args]  # fmt: skip
    code, got = _run(photo_file, "-o", tmp_path / "maps", *args, capsys=capsys)
    assert code == 2 and says in got.err, got.err
    assert got.err.startswith("svbrdf-models") and " error: " in got.err and got.err.count("\n") == 1, got.err
    assert not (tmp_path / "maps").exists()


def test_command_photo_too_small_to_refine_is_reported(tmp_path, capsys):
    """A photo refused (here under capture's 64 px minimum) is one error line; all failed: exit 2."""
    small = write_image(tmp_path / "small.png", torch.rand(3, 40, 40))
    code, got = _run(small, "-o", tmp_path / "maps", "--refine", 2, capsys=capsys)
    assert code == 2
    assert f"svbrdf-models: error: {small}: is 40x40, smaller than 64 px" in got.err
    assert "Traceback" not in got.err


def test_command_interrupted_during_refinement_writes_nothing_of_that_photo(
    tmp_path, photo_file, monkeypatch, capsys
):
    """Ctrl-C during the second photo's refinement: exit 130; the first photo's folder is whole, the
    second has no folder at all, and summary.json lists the first photo only, marked interrupted."""
    second = write_image(tmp_path / "second.png", linear_to_srgb(_photo(64, "leather")))
    real_call = ProgressBar.__call__

    def interrupt(self, step, total, loss):
        if self.name == "second.png" and step == 2:
            raise KeyboardInterrupt
        return real_call(self, step, total, loss)

    monkeypatch.setattr(ProgressBar, "__call__", interrupt)
    out = tmp_path / "maps"
    code, got = _run(photo_file, second, "-o", out, "--refine", 3, "--relit", "none", capsys=capsys)
    assert code == 130
    assert f"svbrdf-models: interrupted: {second} not written" in got.err and "Traceback" not in got.err
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "tiles"]
    assert len(list((out / "tiles").iterdir())) == 6 + len(MATERIAL)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and [e["name"] for e in summary["entries"]] == ["tiles"]


def test_a_signal_whose_interrupt_python_dropped_still_stops_the_batch(tmp_path, photo_file, monkeypatch, capsys):
    """SIGTERM whose KeyboardInterrupt was dropped (it landed in a weakref callback): the batch
    takes the stop at the next refinement step all the same, as it would Ctrl-C."""
    from svbrdf_render.plumbing import processes

    second = write_image(tmp_path / "second.png", linear_to_srgb(_photo(64, "leather")))
    real_call = ProgressBar.__call__

    def dropped(self, step, total, loss):
        if self.name == "second.png" and step == 1:
            processes._STOP["signal"] = "SIGTERM"  # what the handler records before its raise is lost
        return real_call(self, step, total, loss)

    monkeypatch.setattr(ProgressBar, "__call__", dropped)
    out = tmp_path / "maps"
    code, got = _run(photo_file, second, "-o", out, "--refine", 3, "--relit", "none", capsys=capsys)
    assert code == 130, got.err
    assert f"svbrdf-models: interrupted: {second} not written" in got.err
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "tiles"]
    assert processes._STOP["signal"] is None  # nothing left pending after the command


def test_progress_bar_draws_on_a_terminal_only():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty, pipe = Tty(), io.StringIO()
    for stream in (tty, pipe):
        bar = ProgressBar("shot.png", stream)
        for step in range(1, 11):
            bar(step, 10, 0.5 / step)
        bar.close()
    assert pipe.getvalue() == ""
    text = tty.getvalue()
    assert text.startswith("\rshot.png: refining ") and text.endswith("\n")
    assert "10/10 [####################]" in text and "loss 0.0500" in text


def test_the_status_line_redraws_in_place_with_messages_above_it():
    """The one progress display (the refinement bar and a fit's step line draw through it):
    on a terminal, redraws in place at most every ``tty_every_s`` (unless forced), blanks the end
    of a longer line, clears itself for a message and redraws at once after it; into a pipe,
    whole lines or nothing, never a ``\\r``."""
    from svbrdf_render.plumbing import StatusLine

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty = Tty()
    line = StatusLine(tty, tty_every_s=3600)
    assert line.show("step 10/100 long")
    assert not line.show("too soon") and line.show("step 11", force=True)
    line.message("a note")
    assert line.show("step 12")  # the first after a message is not held back
    line.close()
    assert tty.getvalue() == (
        "\rstep 10/100 long" + "\rstep 11" + " " * 9 + "\r" + " " * 7 + "\r" + "a note\n" + "\rstep 12\n"
    )
    pipe, silent = io.StringIO(), io.StringIO()
    lines, quiet = StatusLine(pipe, file_every_s=0.0), StatusLine(silent)
    for status in (lines, quiet):
        status.show("step 1")
        status.message("a note")
        status.show("step 2")
        status.close()
    assert pipe.getvalue() == "step 1\na note\nstep 2\n" and silent.getvalue() == "a note\n"
    assert isinstance(ProgressBar("shot.png", pipe).line, StatusLine)


def test_help_reads_the_default_budget_and_limits(capsys):
    assert main(["predict", "--help"]) == 0
    text = capsys.readouterr().out
    assert f"default: {DEFAULT_REFINE_STEPS}" in text and f"under {MIN_REFINE_SIDE} px" in text
    assert "130" in text and "Exit status: 0 every photo captured" in text


# -- EXIF orientation ----------------------------------------------------------------------------


def _png16_with_orientation(path, pixels, orientation: int):
    """A 16-bit RGB PNG (written by pypng) with an eXIf chunk holding ``orientation``."""
    import struct
    import zlib

    import png
    from PIL import Image

    h, w, _ = pixels.shape
    buf = io.BytesIO()
    png.Writer(w, h, bitdepth=16, greyscale=False).write(buf, pixels.reshape(h, w * 3).tolist())
    exif = Image.Exif()
    exif[0x0112] = orientation
    body = exif.tobytes()[6:]  # without the "Exif\0\0" header JPEG's APP1 has and PNG's eXIf has not
    chunk = struct.pack(">I", len(body)) + b"eXIf" + body + struct.pack(">I", zlib.crc32(b"eXIf" + body))
    data, end_of_ihdr = buf.getvalue(), 8 + 8 + 13 + 4
    path.write_bytes(data[:end_of_ihdr] + chunk + data[end_of_ihdr:])
    return path


@pytest.mark.parametrize("orientation", range(1, 9))
def test_a_16_bit_photo_is_oriented_as_pillow_orients_each_channel(tmp_path, orientation):
    """Pillow holds no 16-bit RGB image, so ``PIL.ImageOps.exif_transpose`` cannot turn such a
    photo whole; load_photo turns the decoded tensor (``photos.orient``). Channel by channel, as
    16-bit grey images, Pillow turns it the same way, to the last of the 65536 levels."""
    import numpy as np
    from PIL import Image, ImageOps

    pixels = np.random.default_rng(orientation).integers(0, 65536, (72, 96, 3), dtype=np.uint16)
    path = _png16_with_orientation(tmp_path / "shot.png", pixels, orientation)
    got, notes = capture.load_photo(path, linear=True)
    channels = []
    for c in range(3):
        grey = Image.fromarray(pixels[..., c])  # mode I;16
        grey.getexif()[0x0112] = orientation
        channels.append(np.asarray(ImageOps.exif_transpose(grey), dtype=np.float32) / 65535)
    shown = torch.from_numpy(np.stack(channels))
    assert shown.shape[1:] == ((96, 72) if orientation >= 5 else (72, 96))
    assert torch.equal(got, square_photo(shown, None))
    assert (f"EXIF orientation {orientation} applied" in notes) == (orientation != 1)
    assert "16-bit PNG read at full precision" in notes


# -- the photo tool stands alone -----------------------------------------------------------------


def test_the_photo_tool_imports_no_trainer_tracking_or_click(tmp_path, photo_file):
    """svbrdf-models predict, run to the end with refinement, loads nothing of svbrdf-train,
    svbrdf-bench, mlflow, h5py or click (Pillow and PyYAML, the photo extra, are allowed)."""
    code = (
        "import sys\n"
        "from svbrdf_models.cli import main\n"
        f"status = main(['predict', {str(photo_file)!r}, '-o', {str(tmp_path / 'maps')!r}, '--refine', '2',"
        " '--relit', 'png'])\n"
        "bad = sorted(m for m in ('mlflow', 'h5py', 'click', 'svbrdf_train', 'svbrdf_bench') if m in sys.modules)\n"
        "print(status, ','.join(bad) or 'none')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-2:] == ["0", "none"], r.stdout


def test_the_network_only_path_imports_no_compiler(tmp_path, photo_file):
    """--refine 0 runs no torch.optim optimiser: its first step imports torch._dynamo (~0.8 s on
    a CPU, a third of the command's time); the flash fit steps by hand."""
    code = (
        "import sys\n"
        "from svbrdf_models.cli import main\n"
        f"status = main(['predict', {str(photo_file)!r}, '-o', {str(tmp_path / 'maps')!r}, '--refine', '0'])\n"
        "print(status, 'torch._dynamo' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-2:] == ["0", "False"], r.stdout


def test_the_photo_extra_is_declared():
    from importlib.metadata import requires

    photo = [r for r in requires("svbrdf-models") or [] if 'extra == "photo"' in r]
    render = [r for r in photo if r.startswith("svbrdf-render[")]
    assert len(render) == 1 and len(photo) == 2
    assert set(render[0].split("[")[1].split("]")[0].split(",")) == {"io", "exr"}  # images; --exr
    # OpenCV finds the printed frame's markers (svbrdf_models.capture.frame)
    assert [r.split(">")[0] for r in photo if r not in render] == ["opencv-python-headless"]


def test_auto_backend_compiles_large_photos_only():
    from svbrdf_models.capture.refining import COMPILE_PIXELS, pick_backend
    from svbrdf_models.errors import DataError

    assert pick_backend("auto", 256, 256) == "eager"
    assert pick_backend("auto", 1024, 1024) == "compiled"
    assert pick_backend("auto", COMPILE_PIXELS, 1) == "compiled"
    assert pick_backend("eager", 4096, 4096) == "eager"
    with pytest.raises(DataError, match="backend"):
        pick_backend("gpu", 8, 8)


def test_the_start_of_a_refinement_loses_the_two_pixel_pattern():
    """Transposed convolutions leave a 2-pixel checkerboard in a network's maps; the start and
    prior of a refinement are filtered so that it is gone (its Nyquist energy is 0), while a
    coarser pattern (8 pixels) keeps most of its amplitude."""
    from svbrdf_models.capture.refining import without_checkerboard
    from svbrdf_render import SVBRDF

    y, x = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="ij")
    checker = ((x + y) % 2).float()[None, None] * 0.2 - 0.1
    coarse = torch.sin(2 * torch.pi * x / 8).float()[None, None] * 0.1
    maps = SVBRDF.constant(1, 32, diffuse=(0.5, 0.5, 0.5))
    noisy = SVBRDF(maps.normal, maps.diffuse + checker, maps.roughness + checker, maps.specular + 0.2 + checker)
    out = without_checkerboard(noisy)
    inner = (slice(None), slice(None), slice(1, -1), slice(1, -1))
    assert torch.allclose(out.diffuse[inner], torch.full_like(out.diffuse[inner], 0.5), atol=1e-6)
    assert torch.allclose(out.roughness[inner], torch.full_like(out.roughness[inner], 0.5), atol=1e-6)
    kept = without_checkerboard(SVBRDF(maps.normal, maps.diffuse + coarse, maps.roughness, maps.specular))
    amplitude = float((kept.diffuse - 0.5)[inner].abs().max())
    assert 0.07 < amplitude <= 0.1
    assert torch.allclose(out.normal.norm(dim=1), torch.ones(1, 32, 32), atol=1e-5)


# -- a black photo, and tiles the memory cannot hold (issue 27) ----------------------------------


def test_a_black_photo_is_captured_with_a_note_not_silently(tmp_path, capsys):
    photo = write_image(tmp_path / "black.png", torch.zeros(3, 72, 72))
    code, out = _run(photo, "--refine", "0", "--relit", "none", "-o", tmp_path / "maps", capsys=capsys)
    assert code == 0, out.err
    entry = json.loads((tmp_path / "maps" / "summary.json").read_text())["entries"][0]
    assert entry["status"] == "ok"
    assert any("black" in note for note in entry["notes"]), entry["notes"]
    assert "black" in out.err
    lit = write_image(tmp_path / "lit.png", linear_to_srgb(_photo(72)))
    _, notes = capture.load_photo(lit)
    assert not any("black" in note for note in notes)


def test_tiles_the_memory_cannot_hold_are_refused_before_the_model_loads(tmp_path, photo_file, monkeypatch, capsys):
    def no_model(*args, **kwargs):
        raise AssertionError("the model was loaded before the size was judged")

    monkeypatch.setattr(machine, "available_memory", lambda: 2**30)
    monkeypatch.setattr(sm.modelfile, "load_model", no_model)
    code, out = _run(photo_file, "--tiles", "--map-size", "8192", "--refine", "0", "-o", tmp_path / "maps",
                     capsys=capsys)  # fmt: skip
    assert code == 2
    lines = out.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("svbrdf-models: error: --tiles --map-size 8192: "), out.err
    assert "GiB of memory, but 1.0 GiB are available" in lines[0] and "at most" in lines[0]
    assert not (tmp_path / "maps" / "tiles").exists()


def test_a_tiled_capture_says_its_cost_and_checks_each_photo(tmp_path, photo_file, model, monkeypatch, capsys):
    code, out = _run(photo_file, "--tiles", "--map-size", "256", "--refine", "0", "--relit", "none",
                     "-o", tmp_path / "maps", capsys=capsys)  # fmt: skip
    assert code == 0, out.err
    cost = capture.tiled_capture_bytes(256) / 2**30
    assert f"--tiles --map-size 256: {capture.tile_count(256, model.resolution)} tiles" in out.err
    assert f"about {cost:.1f} GiB of memory" in out.err
    # without --map-size the size is each photo's own: judged per photo, before its tiles run
    monkeypatch.setattr(machine, "available_memory", lambda: 2**20)
    with pytest.raises(DataError) as e:
        capture.capture_one(model, photo_file, tmp_path / "one", capture.CaptureOptions(tiles=True))
    assert str(e.value).startswith(f"{photo_file}: --tiles: a tiled capture of ")
    assert not (tmp_path / "one").exists()
