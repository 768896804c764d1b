"""Several handheld shots of one material in the printed frame (``predict --shots``,
:mod:`svbrdf_models.capture.shots`): each shot's camera and flash from its markers, its exposure
from the reference strip, one material refined against all of them, and every bad input
refused in one line with nothing written.

The shots are synthetic (tests/models/shotphotos.py): a leather rendered by the project's
renderer in the window under each shot's camera and flash, the sheet a matte paper lit by the
same flash, photographed through the pose's homography with the exposure changed between shots."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from shotphotos import FLASH_OFFSET, PAPER, ShotTruth, fov, focal_35mm, look_at, save, shot

from svbrdf_models.capture.frame import FrameLayout
from svbrdf_models.capture.strip import card_shading
from svbrdf_models.cli import main
from svbrdf_render import Camera, PointLight, Scene, render
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import read_map_folder
from svbrdf_render.geometry import surface_positions
from svbrdf_render.refinement.fit import card_maps

pytest.importorskip("cv2", reason="opencv-python-headless (svbrdf-models[photo]) is not installed")

LAYOUT = FrameLayout()
INTENSITY = 90.0  # half-widths
#: name -> (camera in frame cm, exposure, the photo's up)
SHOTS = {
    "s0": ((0.5, 0.5, 30.0), 1.0, (0.0, 1.0, 0.0)),  # the most frontal
    "s1": ((3.5, 2.5, 27.0), 1.25, (0.2, 1.0, 0.0)),
    "s2": ((-3.0, -2.5, 28.0), 0.8, (-0.1, 1.0, 0.0)),
}
HELD_OUT = [(2.5, -3.0, 29.0), (-3.0, 3.0, 28.0)]  # views no shot was taken from
FOV = f"{fov():.4f}"
QUICK = ["--relit", "none", "--backend", "eager"]


@pytest.fixture(scope="module")
def truth():
    return example_material("leather", 64)


class _Shots(dict):
    """The shots' files (PNG, no EXIF), made when first asked for: ``shots[name]``; and the
    good ones' truths, ``shots.truths``."""

    def __init__(self, folder, truth):
        super().__init__()
        self.folder, self.truth, self.truths = folder, truth, {}

    def __missing__(self, name):
        if name in SHOTS:
            camera, exposure, up = SHOTS[name]
            seed = list(SHOTS).index(name)
            photo, self.truths[name] = shot(self.truth, camera, intensity=INTENSITY, exposure=exposure, up=up,
                                            seed=seed)  # fmt: skip
        elif name == "odd":  # another material
            photo, _ = shot(example_material("tiles", 64), SHOTS["s2"][0], intensity=60.0, seed=5)
        elif name == "clipped":  # the strip's paper brighter than the flash lets it be
            photo, _ = shot(self.truth, SHOTS["s2"][0], intensity=INTENSITY, strip_scale=3.0, seed=6)
        elif name == "other-frame":  # the 8 cm frame's markers
            photo, _ = shot(self.truth, SHOTS["s1"][0], intensity=INTENSITY, layout=FrameLayout(window_cm=8),
                            seed=7)  # fmt: skip
        else:  # "table": no frame at all
            ramp = np.linspace(40, 200, 800, dtype=np.float32)
            photo = np.stack([np.tile(ramp * k, (600, 1)) for k in (1.0, 0.8, 0.6)], axis=-1).astype(np.uint8)
        self[name] = self.folder / f"{name}.png"
        save(self[name], photo)
        return self[name]


@pytest.fixture(scope="module")
def shots(tmp_path_factory, truth):
    made = _Shots(tmp_path_factory.mktemp("shots"), truth)
    for name in SHOTS:
        made[name]
    return made


def _run(*args, capsys):
    code = main(["predict", *map(str, args)])
    return code, capsys.readouterr()


def _record(folder) -> dict:
    return json.loads((folder / "material.json").read_text())


def _held_out_scene(camera):
    rot, _ = look_at(camera)
    flash = np.asarray(camera) + rot.T @ np.array([FLASH_OFFSET[0], -FLASH_OFFSET[1], 0.0])
    return ShotTruth(np.asarray(camera), flash, INTENSITY, 1.0).scene(LAYOUT)


# -- the strip read through the renderer ----------------------------------------------------------


def test_the_card_is_shaded_by_the_renderer_at_points_off_the_patch():
    camera, flash = torch.tensor([0.3, -0.2, 5.0]), torch.tensor([0.5, -0.2, 4.9])
    on_patch = card_shading(surface_positions(32, 32)[:2], camera, flash, PAPER)
    direct = render(card_maps(PAPER, (32, 32)), Scene(Camera(camera), (PointLight(flash, 1.0),)))[0]
    assert torch.allclose(on_patch, direct, rtol=1e-4)
    # the strip, outside the patch: Lambert's albedo / pi cos / d^2, plus a matte card's small specular
    ys, xs = torch.meshgrid(torch.linspace(-1.8, -1.6, 4), torch.linspace(-1.4, 1.4, 50), indexing="ij")
    xy = torch.stack([xs, ys])
    to_light = flash[:, None, None] - torch.cat([xy, torch.zeros(1, 4, 50)])
    d2 = to_light.square().sum(0)
    lambert = PAPER / math.pi * to_light[2] / d2.sqrt() / d2
    ratio = card_shading(xy, camera, flash, PAPER) / lambert
    assert float(ratio.min()) > 1.0 and float(ratio.max()) < 1.03


def _page_data(page) -> dict:
    text = page.read_text()
    return json.loads(re.search(r'<script type="application/json" id="svbrdf-data">(.*?)</script>', text, re.S).group(1))


# -- the capture --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_three_shots_are_posed_exposed_and_beat_the_frontal_shot_alone(tmp_path, shots, truth, capsys):
    files, truths = shots, shots.truths
    names = list(SHOTS)
    out = tmp_path / "three"
    code, got = _run(*(files[n] for n in names), "--shots", "--fov", FOV, "--strip-albedo", PAPER, "-o", out,
                     "--refine", 60, "--map-size", 64, "--bits", 16, *QUICK, capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    folder = out / "s0"
    assert got.out.strip() == str(folder)
    record = _record(folder)
    assert [s["file"] for s in record["shots"]] == [f"{n}.png" for n in names]
    for s, name in zip(record["shots"], names):
        t = truths[name]
        for key, want in (("camera", t.camera(LAYOUT)), ("light", t.flash(LAYOUT))):
            assert torch.linalg.norm(torch.tensor(s[key]) - want) / torch.linalg.norm(want) < 0.02, (name, key)
        # the flash read off the strip: the paper's albedo stated, each shot's exposure found
        assert s["intensity"] == pytest.approx(INTENSITY * t.exposure, rel=0.04), name
        assert s["exposure"] == "strip" and s["gain"] == 1.0 and s["used"]
        assert s["focal_source"] == "fov" and s["flash_offset_cm"] == list(FLASH_OFFSET)
        assert s["residual"] < 0.25 and s["rmse"] < s["rmse_network"]
    assert [s["network_view"] for s in record["shots"]] == [True, False, False]
    assert record["refine"]["views"] == 3 and record["refine"]["gains"] == "fixed"
    # three shots: each map's pull towards the network's start a third of one photo's, per pixel
    assert record["refine"]["coarse"] == 0 and record["refine"]["prior"]["normal"] == pytest.approx(2.0 / 3)
    assert record["refine"]["clipped"] == "lower bound" and record["refine"]["prior_relief"] == shots_prior_relief()
    assert record["frame"]["window_cm"] == LAYOUT.window_cm and record["frame"]["strip_albedo"] == PAPER
    lights = _page_data(folder / "index.html")["shots"]  # the viewer's keys 1-9: each shot's flash
    assert [s["name"] for s in lights] == [f"{n}.png" for n in names]
    assert lights[1]["light"] == pytest.approx(record["shots"][1]["light"], abs=1e-4)

    alone = tmp_path / "alone"  # the most frontal shot alone, as a calibrated single capture
    code, got = _run(files["s0"], "--shots", "--fov", FOV, "--strip-albedo", PAPER, "-o", alone,
                     "--refine", 60, "--map-size", 64, "--bits", 16, *QUICK, capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    assert _record(alone / "s0")["refine"]["coarse"] == 8  # one shot: a single photo's settings
    assert _record(alone / "s0")["refine"]["prior_relief"] == 1.0
    three, one = read_map_folder(folder), read_map_folder(alone / "s0")
    for camera in HELD_OUT:  # relit where no shot was taken from
        scene = _held_out_scene(camera)
        target = render(truth, scene).clamp(0, 1)
        errors = [float((render(m, scene).clamp(0, 1) - target).square().mean().sqrt()) for m in (three, one)]
        assert errors[0] < 0.97 * errors[1], errors
    for name in ("diffuse", "roughness"):
        errors = [float((getattr(m, name) - getattr(truth, name)).square().mean().sqrt()) for m in (three, one)]
        assert errors[0] < errors[1], (name, errors)


def test_without_a_strip_albedo_the_exposures_are_relative_to_the_frontal_shot(tmp_path, shots, capsys):
    files, truths = shots, shots.truths
    jpegs = []
    for name in [*SHOTS, "clipped"]:  # the focal length from the EXIF this time
        path = tmp_path / f"{name}.jpg"
        save(path, np.asarray(Image.open(files[name])), focal_35mm=focal_35mm())
        jpegs.append(path)
    code, got = _run(*jpegs, "--shots", "-o", tmp_path / "out", "--refine", 3, "--map-size", 64, *QUICK,
                     capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    shots_ = _record(tmp_path / "out" / "s0")["shots"]
    assert [s["exposure"] for s in shots_] == ["relative", "relative", "relative", "free"]
    for s, name in zip(shots_[:3], SHOTS):
        assert s["focal_source"] == "exif-35mm"
        want = truths[name].camera(LAYOUT)
        assert torch.linalg.norm(torch.tensor(s["camera"]) - want) / torch.linalg.norm(want) < 0.02
        ratio = s["intensity"] / shots_[0]["intensity"]
        assert ratio == pytest.approx(truths[name].exposure / truths["s0"].exposure, rel=0.03), name
    assert math.isfinite(shots_[3]["gain"]) and shots_[3]["strip"]["readable"] is False


def test_a_shot_without_the_frame_is_skipped_with_a_line_and_the_others_go_on(tmp_path, shots, capsys):
    files = shots
    code, got = _run(files["s0"], files["table"], files["s1"], "--shots", "--fov", FOV, "-o", tmp_path,
                     "--refine", 0, *QUICK, capsys=capsys)  # fmt: skip
    assert code == 0, got.err
    skipped = [line for line in got.err.splitlines() if "table.png" in line]
    assert len(skipped) == 1 and "frame not found in" in skipped[0] and "skipped" in skipped[0]
    record = _record(tmp_path / "s0")
    assert [(s["file"], s["used"]) for s in record["shots"]] == [("s0.png", True), ("s1.png", True),
                                                                 ("table.png", False)]  # fmt: skip
    assert "frame not found" in record["shots"][2]["skipped"]


# -- bad input: one line, exit 2, nothing written --------------------------------------------------

BAD = {
    "no shot shows the frame": (["table", "table"], [], "the frame was found in none of the 2 shot(s) (table.png, "),
    "shots of two materials": (["s0", "s1", "odd"], ["--refine", "30", "--map-size", "64"],
                               "shots of different materials? {odd} is not explained"),
    "a clipped strip with its albedo stated": (["s0", "clipped"], ["--strip-albedo", "0.8"],
                                               "{clipped}: --strip-albedo 0.8: the frame's reference strip is "),
    "markers of another frame": (["s0", "other-frame"], [], "markers of another frame in {other_frame}: the 8 cm"),
    "no focal length": (["s0"], ["--no-fov"], "{s0}: no focal length in its EXIF; give --fov DEG"),
    "--fov 0.5": (["s0"], ["--fov", "0.5"], "--fov 0.5: the field of view"),
    "--fov 179": (["s0"], ["--fov", "179"], "--fov 179.0: the field of view"),
    "--shots with --crop": (["s0"], ["--crop", "0,0,100"], "--shots with --crop"),
    "--strip-albedo without --shots": (["s0"], ["--no-shots", "--strip-albedo", "0.8"],
                                       "--strip-albedo goes with --shots"),
}  # fmt: skip


@pytest.mark.parametrize("how", list(BAD))
def test_bad_shots_are_refused_in_one_line_with_nothing_written(tmp_path, shots, how, capsys):
    files = shots
    names, extra, says = BAD[how]
    flags = ["--shots"] if "--no-shots" not in extra else []
    if "--no-fov" not in extra and "--fov" not in extra:
        flags += ["--fov", FOV]
    extra = [a for a in extra if a not in ("--no-shots", "--no-fov")]
    if "--refine" not in extra:
        extra += ["--refine", "2", "--map-size", "64"]
    out = tmp_path / "out"
    code, got = _run(*(files[n] for n in names), *flags, *extra, "-o", out, *QUICK, capsys=capsys)
    assert code == 2, got.err
    lines = got.err.strip().splitlines()
    error = [line for line in lines if "error:" in line]
    assert len(error) == 1 and error[0] == lines[-1], got.err
    assert says.format(**{n.replace("-", "_"): files[n] for n in names}) in error[0], got.err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    ("network", "refined", "refused"),
    [
        ([0.20, 0.22, 1.03], [0.09, 0.05, 0.19], "c.jpg"),  # another material: both stand out
        ([0.20, 0.22, 1.03], [0.05, 0.05, 0.07], None),  # the network's start missed it, refining explained it
        ([0.20, 0.22, 0.25], [0.02, 0.02, 0.12], None),  # the start explains it as well as the others
        ([0.05, 0.06, 0.20], [0.01, 0.01, 0.10], None),  # stands out, but all explained well (floor)
    ],
)
def test_a_shot_is_of_another_material_when_neither_the_start_nor_the_refinement_explains_it(
        network, refined, refused):  # fmt: skip
    from types import SimpleNamespace

    from svbrdf_models.capture.shotcapture import check_residuals
    from svbrdf_models.errors import DataError

    shots = SimpleNamespace(shots=[SimpleNamespace(path=Path(n)) for n in ("a.jpg", "b.jpg", "c.jpg")])
    if refused is None:
        check_residuals(shots, torch.tensor(refined), torch.tensor(network))
    else:
        with pytest.raises(DataError, match=f"shots of different materials\\? {refused} is not explained"):
            check_residuals(shots, torch.tensor(refined), torch.tensor(network))


def test_clipped_pixels_are_kept_as_lower_bounds_and_their_neighbours_left_out():
    from svbrdf_models.capture import shots as shots_module

    windows = torch.full((2, 3, 9, 9), 0.3)
    windows[0, :, 4, 4] = 1.0  # a clipped highlight of one pixel
    windows[1, 1, 0, 0] = 0.99  # one channel is enough
    masks = torch.ones(2, 1, 9, 9)
    masks[0, :, 3:6, 3:6] = 0  # as prepare_shots leaves them: the clipped pixel and its neighbours out
    masks[1, :, 0:2, 0:2] = 0
    fitted = shots_module.fitted_masks(windows, masks)
    assert fitted[0, 0, 4, 4] == 1 and fitted[1, 0, 0, 0] == 1  # the clipped pixels: in, as bounds
    assert fitted[0, 0, 3:6, 3:6].sum() == 1 and fitted[1, 0, 0:2, 0:2].sum() == 1  # their neighbours: out
    assert torch.equal(fitted[0, 0, :3], masks[0, 0, :3])


def test_clipped_pixels_held_as_lower_bounds_make_a_metal_as_bright_as_its_photos():
    """A bright metal clips over much of each shot. Left out of the loss, those pixels tell the
    refinement nothing, and a start too dark there stays dark; kept as lower bounds (the
    rendering clipped to [0, 1] as the camera's: at least as bright costs nothing), the
    refinement has to reach the clip level there."""
    from svbrdf_models.capture import shots as shots_module
    from svbrdf_render import RefineSettings, refine_views
    from svbrdf_render.maps import SVBRDF

    n = 32
    flat = torch.zeros(1, 3, n, n)
    flat[:, 2] = 1

    def metal(specular):
        return SVBRDF(normal=flat, diffuse=torch.full((1, 3, n, n), 0.02), roughness=torch.full((1, 1, n, n), 0.45),
                      specular=torch.full((1, 3, n, n), specular))  # fmt: skip

    scenes = [Scene(Camera(torch.tensor([x, y, 2.5])), (PointLight(torch.tensor([x + 0.1, y, 2.5]), 12.0),))
              for x, y in ((0.0, 0.0), (0.5, -0.4), (-0.5, 0.4))]  # fmt: skip
    photos = torch.cat([render(metal(0.9), s) for s in scenes]).clamp(0, 1)
    clipped = (photos.amax(1, keepdim=True) >= shots_module.CLIPPED).float()
    assert 0.02 < float(clipped.mean()) < 0.5  # a bright patch a shot, not the whole shot
    masks = 1 - torch.nn.functional.max_pool2d(clipped, 3, stride=1, padding=1)
    fitted = shots_module.fitted_masks(photos, masks)
    settings = RefineSettings(prior={"normal": 0.4, "diffuse": 0.06, "roughness": 0.01, "specular": 0.04}, coarse=0)
    reached = {}
    for name, weights in (("left out", masks), ("lower bound", fitted)):
        result = refine_views(photos, metal(0.3), scenes, masks=weights, steps=60, settings=settings, backend="eager")
        for k in ("normal", "diffuse", "roughness", "specular"):
            assert torch.isfinite(getattr(result.svbrdf, k)).all()
        again = torch.cat([render(result.svbrdf, s) for s in scenes]).clamp(0, 1).amax(1, keepdim=True)
        reached[name] = float(again[clipped.bool()].mean())
    assert reached["lower bound"] > shots_module.CLIPPED - 0.05 > reached["left out"], reached


def test_several_shots_pull_the_normals_towards_a_share_of_the_networks_relief():
    """The network's normals of a flat material carry relief it made up. Pulled towards them,
    the refinement keeps much of it where the shots contradict it weakly; pulled towards a
    flatter surface (several shots: ``SHOTS_PRIOR_RELIEF`` of the network's slopes), less."""
    from svbrdf_models.capture.shots import SHOTS_PRIOR_RELIEF
    from types import SimpleNamespace

    from svbrdf_models.capture.multiview import refine_network
    from svbrdf_render.maps import SVBRDF

    n = 32
    truth = example_material("leather", n)
    flat = torch.zeros(1, 3, n, n)
    flat[:, 2] = 1
    truth = SVBRDF(flat, truth.diffuse, truth.roughness, truth.specular)
    g = torch.linspace(-1, 1, n)
    y, x = torch.meshgrid(g, g, indexing="ij")
    bumps = torch.stack([0.3 * torch.sin(9 * x), 0.3 * torch.cos(7 * y), torch.ones_like(x)])[None]
    network = SVBRDF(bumps / bumps.norm(dim=1, keepdim=True), truth.diffuse, truth.roughness, truth.specular)
    scenes = [Scene(Camera(torch.tensor([x0, y0, 3.0])), (PointLight(torch.tensor([x0 + 0.1, y0, 3.0]), 12.0),))
              for x0, y0 in ((0.0, 0.0), (0.6, -0.5), (-0.6, 0.5))]  # fmt: skip
    photos = torch.cat([render(truth, s) for s in scenes]).clamp(0, 1)
    options = SimpleNamespace(refine=40, refine_seconds=None, backend="eager", metal="auto")
    error = {}
    for relief in (1.0, SHOTS_PRIOR_RELIEF, 0.0):
        result = refine_network(network, photos, scenes, options, None, torch.device("cpu"), prior_relief=relief)
        normal = result.svbrdf.normal
        assert torch.isfinite(normal).all()
        error[relief] = float((normal - flat).square().mean().sqrt())
    assert error[0.0] < error[SHOTS_PRIOR_RELIEF] < 0.9 * error[1.0], error


def shots_prior_relief() -> float:
    """The share of the network's relief several shots pull the normals towards."""
    from svbrdf_models.capture.shots import SHOTS_PRIOR_RELIEF

    return SHOTS_PRIOR_RELIEF


def test_flatter_scales_each_normals_slope_and_stays_finite_at_grazing_normals():
    from svbrdf_models.capture.multiview import flatter
    from svbrdf_render.maps import SVBRDF

    n = torch.tensor([[0.6, -0.3, 0.74], [0.0, 1.0, 0.0], [1.0, 0.0, 1e-9], [0.0, 0.0, 1.0]])  # the last: flat
    n = (n / n.norm(dim=1, keepdim=True)).T.reshape(1, 3, 2, 2).requires_grad_(True)
    maps = SVBRDF(n, torch.full((1, 3, 2, 2), 0.3), torch.full((1, 1, 2, 2), 0.5), torch.full((1, 3, 2, 2), 0.04),
                  validate=False)  # fmt: skip
    same, half, flat = (flatter(maps, r).normal for r in (1.0, 0.5, 0.0))
    assert torch.allclose(same[..., 0, 0], n[..., 0, 0], atol=1e-6)
    slope = lambda t: t[0, :2, 0, 0] / t[0, 2, 0, 0]  # noqa: E731
    assert torch.allclose(slope(half), 0.5 * slope(n), atol=1e-6)
    assert torch.allclose(flat, torch.tensor([0.0, 0.0, 1.0])[None, :, None, None].expand_as(flat))
    for t in (same, half, flat):
        assert torch.isfinite(t).all() and torch.allclose(t.norm(dim=1), torch.ones(1, 2, 2), atol=1e-5)
    half.sum().backward()
    assert torch.isfinite(n.grad).all()
