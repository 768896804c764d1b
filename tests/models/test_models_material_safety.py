"""Nothing lost by ``svbrdf-models predict``: a folder made from a photo's name never leaves
``-o``, two captures of photos of the same name into one ``-o`` cannot both win, and
``summary.json`` keeps the entries of earlier runs (issue 36, "Data lost")."""

from __future__ import annotations

import json
import multiprocessing
from pathlib import Path

import pytest
import torch

from svbrdf_models.capture.batch import folder_name
from svbrdf_models.capture.batch import write_summary
from svbrdf_models.cli import main
from svbrdf_render import render, write_image
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.plumbing import locked

FAST = ["--refine", "0", "--relit", "none"]


def _photo_file(path: Path, name: str = "tiles", size: int = 64) -> Path:
    from svbrdf_render import Scene

    photo = render(example_material(name, size), Scene.flash(intensity=12.0)).clamp(0, 1)[0]
    return write_image(path, linear_to_srgb(photo))


@pytest.mark.parametrize(
    ("name", "folder"),
    [("...png", "photo"), ("..png", "photo"), (".hidden.png", "hidden"), ("a.b.png", "a.b")],
)
def test_a_folder_named_after_a_photo_stays_inside_out(name, folder):
    assert folder_name(Path(name), set()) == folder
    assert folder_name(Path(name), {folder}) == f"{folder}-2"


def test_a_photo_named_dots_does_not_replace_the_folder_above_out(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text("my page\n")
    photo = _photo_file(site / "...png")
    assert main(["predict", str(photo), "-o", str(site / "out"), *FAST]) == 0
    assert (site / "index.html").read_text() == "my page\n"
    assert (site / "out" / "photo" / "material.json").is_file()
    assert sorted(p.name for p in (site / "out").iterdir()) == ["photo", "summary.json"]


def _capture(args):
    # One torch thread before any torch work: a forked child that enters an OpenMP region its
    # parent already ran deadlocks (GNU OpenMP is not fork-safe; the model's checks hung here).
    # The test is about the folder, not the threads.
    torch.set_num_threads(1)
    photo, out = args
    return main(["predict", photo, "-o", out, *FAST, "--threads", "1"])


def test_two_captures_of_same_named_photos_into_one_folder_lose_nothing(tmp_path):
    """Two photos ``a/tiles.png`` and ``b/tiles.png`` (different materials) captured at once into
    one ``-o``: one wins the folder, the other is refused (exit 2); never both 0 with one lost."""
    a = _photo_file((tmp_path / "a").mkdir() or tmp_path / "a" / "tiles.png", "tiles")
    b = _photo_file((tmp_path / "b").mkdir() or tmp_path / "b" / "tiles.png", "leather")
    for trial in range(3):
        out = tmp_path / f"out{trial}"
        with multiprocessing.get_context("fork").Pool(2) as pool:
            codes = pool.map(_capture, [(str(a), str(out)), (str(b), str(out))])
        assert sorted(codes) == [0, 2], codes
        record = json.loads((out / "tiles" / "material.json").read_text())
        winner = a if codes[0] == 0 else b
        assert record["photo"]["file"] == winner.name
        from svbrdf_models.capture.material import photo_sha256

        assert record["photo"]["sha256"] == photo_sha256(winner)


def test_summary_keeps_earlier_photos_and_replaces_a_photos_own_entry(tmp_path):
    out = tmp_path / "maps"
    write_summary(
        out / "summary.json", [{"name": "a", "photo": "a.png", "status": "ok", "rmse": 0.1}], model="m1"
    )
    write_summary(
        out / "summary.json", [{"name": "b", "photo": "b.png", "status": "ok", "rmse": 0.3}], model="m1"
    )
    second = write_summary(
        out / "summary.json",
        [
            {"name": "a", "photo": "a.png", "status": "ok", "rmse": 0.2},
            {"photo": "c.png", "status": "failed"},
        ],
        model="m2",
    )
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk == second
    assert [(e.get("name"), e.get("rmse")) for e in on_disk["entries"]] == [
        ("b", 0.3),
        ("a", 0.2),
        (None, None),
    ]
    assert (on_disk["photos"], on_disk["captured"], on_disk["failed"]) == (3, 2, 1)
    assert on_disk["median_rmse"] == pytest.approx(0.25) and on_disk["model"] == "m2"


def test_a_rerun_after_an_interrupt_keeps_the_photos_done_before(tmp_path):
    one, two = _photo_file(tmp_path / "one.png"), _photo_file(tmp_path / "two.png", "leather")
    out = tmp_path / "maps"
    assert main(["predict", str(one), "-o", str(out), *FAST]) == 0
    assert main(["predict", str(two), "-o", str(out), *FAST]) == 0
    names = [e["name"] for e in json.loads((out / "summary.json").read_text())["entries"]]
    assert names == ["one", "two"]


def test_the_lock_is_exclusive_across_processes(tmp_path):
    """While one process holds the folder's lock, another waits for it."""
    import time

    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()

    def hold():
        with locked(tmp_path):
            ready.set()
            release.wait(10)

    p = ctx.Process(target=hold)
    p.start()
    assert ready.wait(10)
    waited = ctx.Event()

    def take():
        with locked(tmp_path):
            waited.set()

    q = ctx.Process(target=take)
    q.start()
    time.sleep(0.3)
    assert not waited.is_set()  # still held by the first
    release.set()
    q.join(10)
    p.join(10)
    assert waited.is_set()
    assert list(tmp_path.iterdir()) == []  # a folder's lock writes nothing in it


@pytest.mark.parametrize("stem", ["café", "фото", "2024 shot"])
def test_photo_names_outside_ascii_make_a_material(tmp_path, stem):
    """A photo named in any script is captured (the MaterialX name is made ASCII), where it used
    to fail after the computing was done ("not a MaterialX name")."""
    from svbrdf_render.formats.materialx import _MTLX_NAME

    photo = _photo_file(tmp_path / f"{stem}.png")
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), *FAST]) == 0
    text = (tmp_path / "out" / stem / "material.mtlx").read_text()
    name = text.split('<surfacematerial name="', 1)[1].split('"', 1)[0]
    assert _MTLX_NAME.match(name), name


def test_predict_says_how_many_threads_it_takes_and_refuses_zero(tmp_path, capsys):
    photo = _photo_file(tmp_path / "shot.png")
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), *FAST, "--threads", "1"]) == 0
    assert "1 torch thread (--threads)" in capsys.readouterr().err
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), "--threads", "0"]) == 2


# -- bounded map size for refinement (issue 36: a 12 MP photo was refined at full size) ------


def test_refined_maps_are_bounded_by_default_and_full_on_request(tmp_path, monkeypatch):
    from svbrdf_models.capture import refining

    monkeypatch.setattr(refining, "DEFAULT_MAP_SIZE", 64)
    photo = _photo_file(tmp_path / "big.png", size=96)
    args = ["--refine", "1", "--relit", "none", "--backend", "eager"]
    assert main(["predict", str(photo), "-o", str(tmp_path / "a"), *args]) == 0
    entry = json.loads((tmp_path / "a" / "summary.json").read_text())["entries"][0]
    assert entry["maps"] == 64 and any("--map-size full" in n for n in entry["notes"])
    assert main(["predict", str(photo), "-o", str(tmp_path / "b"), *args, "--map-size", "full"]) == 0
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["entries"][0]["maps"] == 96


def test_a_refinement_the_memory_cannot_hold_is_refused_before_it_starts(tmp_path, monkeypatch, capsys):
    from svbrdf_render.plumbing import machine

    monkeypatch.setattr(machine, "available_memory", lambda: 2**20)
    photo = _photo_file(tmp_path / "shot.png")
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), "--refine", "5", "--relit", "none"]) == 2
    err = capsys.readouterr().err
    assert f"{photo}: refining 64 px maps needs about" in err and "--map-size" in err
    assert not (tmp_path / "out" / "shot").exists()


def test_a_long_refinement_is_announced_before_it_starts(tmp_path, monkeypatch, capsys):
    from svbrdf_models.capture import refining

    monkeypatch.setattr(refining, "REFINE_SECONDS_PER_PIXEL_STEP", 1.0)
    photo = _photo_file(tmp_path / "shot.png")
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), "--refine", "1", "--relit", "none"]) == 0
    err = capsys.readouterr().err
    assert "shot.png: refining 64 px maps for 1 steps: about 4096 s on 2 cores (4096 s of steps" in err


def test_the_announced_time_counts_the_files_and_stops_at_the_time_budget(tmp_path, monkeypatch, capsys):
    from svbrdf_models.capture import refining

    monkeypatch.setattr(refining, "REFINE_SECONDS_PER_PIXEL_STEP", 1.0)
    monkeypatch.setattr(refining, "AFTER_REFINE_SECONDS_PER_PIXEL", 0.01)  # 41 s for 64 px
    photo = _photo_file(tmp_path / "shot.png")
    args = ["predict", str(photo), "-o", str(tmp_path / "out"), "--refine", "1", "--relit", "none"]
    assert main([*args, "--refine-seconds", "20"]) == 0
    err = capsys.readouterr().err
    assert "shot.png: refining 64 px maps for 1 steps: about 61 s on 2 cores (20 s of steps, 41 s" in err


def test_the_viewer_lights_the_material_with_the_flash_material_json_records(tmp_path):
    import re

    photo = _photo_file(tmp_path / "shot.png")
    assert main(["predict", str(photo), "-o", str(tmp_path / "out"), *FAST]) == 0
    folder = tmp_path / "out" / "shot"
    flash = json.loads((folder / "material.json").read_text())["flash"]["intensity"]
    page = (folder / "index.html").read_text()
    data = json.loads(
        re.search(r'<script type="application/json" id="svbrdf-data">(.*?)</script>', page, re.S).group(1)
    )
    assert data["intensity"] == pytest.approx(flash) and flash != pytest.approx(3.14159 * 2.2**2, rel=0.01)


# -- a region of known albedo pins the level (issue 35: --reference X,Y,W,H:ALBEDO) ------------


def _card_photo(path: Path, exposure: float = 1.0, width: int = 96) -> Path:
    """A flash photo (96 px tall, ``width`` wide) of a material with an 18% grey card in it."""
    from svbrdf_render import SVBRDF, Scene

    maps = example_material("tiles", 96)
    normal, diffuse, roughness = maps.normal.clone(), maps.diffuse.clone(), maps.roughness.clone()
    card = (slice(None), slice(None), slice(20, 44), slice(20, 44))  # a flat, matte 18% grey card
    normal[card], diffuse[card], roughness[card] = torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1), 0.18, 0.9
    maps = SVBRDF(normal, diffuse, roughness, maps.specular, validate=False)
    photo = render(maps, Scene.flash(intensity=12.0 * exposure)).clamp(0, 1)[0]
    if width > 96:
        photo = torch.cat([torch.zeros(3, 96, width - 96), photo], dim=2)
    return write_image(path, linear_to_srgb(photo))


def _diffuse_png_mean(folder: Path, box) -> float:
    from svbrdf_render import read_image, srgb_to_linear

    d = srgb_to_linear(read_image(folder / "diffuse.png"))  # diffuse.png is sRGB by default
    t, l, b, r = box
    luma = torch.tensor([0.2126, 0.7152, 0.0722]).view(3, 1, 1)
    return float((d[:, t:b, l:r] * luma).sum(0).mean())


@pytest.mark.parametrize("exposure", [0.5, 2.0])
def test_a_grey_card_pins_the_diffuse_level_whatever_the_exposure(tmp_path, exposure):
    photo = _card_photo(tmp_path / "card.png", exposure)
    out = tmp_path / "out"
    args = ["--refine", "0", "--relit", "none", "--reference", "24,24,16,16:0.18"]
    assert main(["predict", str(photo), "-o", str(out), *args]) == 0
    folder = out / "card"
    record = json.loads((folder / "material.json").read_text())
    assert record["reference"]["albedo"] == 0.18 and record["reference"]["region"] == [24, 24, 16, 16]
    # the maps are at the model's 128 px: the card's 24..40 of 96 px is 32..53 there
    assert _diffuse_png_mean(folder, (34, 34, 51, 51)) == pytest.approx(0.18, abs=0.02)


@pytest.mark.parametrize(
    ("spec", "needle"),
    [("90,90,20,20:0.18", "outside the 96x96 photo"), ("10,10,20,20:0.18", "not inside the square")],
)
def test_a_reference_outside_the_photo_or_the_square_is_refused(tmp_path, capsys, spec, needle):
    photo = _card_photo(tmp_path / "card.png", width=96 if "outside" in needle else 128)
    code = main(["predict", str(photo), "-o", str(tmp_path / "o"), *FAST, "--reference", spec])
    assert code == 2 and needle in capsys.readouterr().err


def test_a_clipped_reference_is_refused(tmp_path, capsys):
    photo = _card_photo(tmp_path / "card.png", exposure=40.0)
    code = main(["predict", str(photo), "-o", str(tmp_path / "o"), *FAST, "--reference", "24,24,16,16:0.18"])
    assert code == 2 and "clipped" in capsys.readouterr().err
