"""benchmarks/shot_simulator.py (issue 44's handheld captures): the simulated photos are what the
capture's own readers expect. In a simulated frame shot the frame finder sees every marker and
places the camera and the flash where the simulator put them; the lens is in the EXIF; the
window, rectified, is the renderer's image of the material under that shot's camera and flash;
the grey card's pixel box lies on the card inside the captured square."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import load_benchmark

pytest.importorskip("cv2", reason="opencv-python-headless (svbrdf-models[photo]) is not installed")


@pytest.fixture(scope="module")
def sim():
    return load_benchmark("shot_simulator")


@pytest.fixture(scope="module")
def material():
    """A 64 px material: a checker of two albedos, gentle bumps, mid roughness."""
    from svbrdf_render import SVBRDF

    n = 64
    g = torch.linspace(-1, 1, n)
    y, x = torch.meshgrid(-g, g, indexing="ij")
    checker = ((torch.floor((x + 1) * 4) + torch.floor((y + 1) * 4)) % 2)[None, None]
    diffuse = torch.cat([0.2 + 0.4 * checker, 0.25 + 0.2 * checker, 0.3 + 0.1 * checker], 1)
    normal = torch.stack([0.15 * torch.sin(6 * x), 0.15 * torch.cos(5 * y), torch.ones_like(x)])[None]
    normal = normal / normal.norm(dim=1, keepdim=True)
    return SVBRDF(normal, diffuse, torch.full((1, 1, n, n), 0.4), torch.full((1, 3, n, n), 0.04))


def _read(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def test_frame_shots_place_camera_and_flash_as_the_frame_finder_reads_them(sim, material, tmp_path):
    from svbrdf_models.capture.framephoto import find_frame, shot_pose
    from svbrdf_models.capture.geometry import exif_focal, focal_pixels

    rng = np.random.default_rng(3)
    phone = sim.draw_phone(rng)
    assert 24 <= phone.focal_35mm <= 28 and 0.8 <= phone.flash_offset_cm[0] <= 1.2
    world = sim.World(material, True, dpi=100)
    for k in range(2):
        shot = sim.draw_shot(rng, phone, 320, "frame")
        assert shot.size == (320, 427) and shot.tilt_deg <= 20 and 1.8 <= shot.distance <= 4.0 + 0.15
        assert 0.5 <= shot.exposure <= 2 and 85 <= shot.jpeg_quality <= 95
        path = sim.save_jpeg(sim.make_photo(world, shot, rng), shot, tmp_path / f"shot{k}.jpg")
        assert path.with_suffix(".json").is_file()
        focal, source = focal_pixels(exif_focal(path))  # the lens as the capture reads it
        assert source == "exif-35mm" and focal == pytest.approx(shot.focal_px, rel=1e-6)
        photo = _read(path)
        found = find_frame(photo, name=path.name)
        assert len(found.ids) == 8
        pose = shot_pose(found, focal, flash_offset_cm=phone.flash_offset_cm)
        for got, true in ((pose.camera, shot.camera), (pose.flash, shot.flash)):
            err = np.linalg.norm(got.numpy() - true) / np.linalg.norm(true)
            assert err < 0.02, (k, got, true)
        # the flash beside the lens, in the camera's plane, about 1 cm (in window half-widths)
        step = (shot.flash - shot.camera) * shot.cm_per_unit
        assert 0.8 <= np.linalg.norm(step) <= 1.3 and abs(step @ shot.rotation[2]) < 1e-9


def test_the_rectified_window_is_the_renderers_image_of_the_material(sim, material, tmp_path):
    """Photo -> JPEG -> find_frame -> rectify gives back render(material, shot's scene) up to
    noise, JPEG and resampling: no bias in level, no shift."""
    from svbrdf_models.capture.framephoto import find_frame, rectify
    from svbrdf_render import linear_to_srgb, render

    rng = np.random.default_rng(5)
    shot = sim.draw_shot(rng, sim.draw_phone(rng), 400, "frame")
    photo = sim.make_photo(sim.World(material, True, dpi=100), shot, rng)
    path = sim.save_jpeg(photo, shot, tmp_path / "s.jpg")
    photo = _read(path)
    found = find_frame(photo)
    m = int(np.linalg.norm(found.window - np.roll(found.window, 1, axis=0), axis=1).min())
    window = rectify(photo, found, m).window[:, 2:-2, 2:-2]
    with torch.no_grad():
        expected = linear_to_srgb(render(material.resize(m, m), shot.scene()).clamp(0, 1))[0, :, 2:-2, 2:-2]
    diff = window - expected
    assert abs(float(diff.mean())) < 0.01
    assert float(diff.square().mean().sqrt()) < 0.04
    shifted = window[:, :, 4:] - expected[:, :, :-4]  # a shift of the checker would match better
    assert float(shifted.square().mean().sqrt()) > float(diff.square().mean().sqrt())


def test_card_shot_box_lies_on_the_card_inside_the_square(sim, material, tmp_path):
    import dataclasses

    rng = np.random.default_rng(7)
    today = sim.draw_shot(rng, sim.draw_phone(rng), 256, "today")
    # without the frame the camera stands where the centred square spans about the patch
    assert today.distance == pytest.approx(today.focal_px / 128, rel=0.05)  # from the aim point: exactly
    card = dataclasses.replace(today, kind="card")
    sim._place_card(card)
    x, y, w, h = card.card_box
    x0, y0, side = sim.square_box(card.size)
    assert x0 <= x and y0 <= y and x + w <= x0 + side and y + h <= y0 + side and w >= 20 and h >= 20
    world = sim.World(material, False, card=card.card)
    path = sim.save_jpeg(sim.make_photo(world, card, rng), card, tmp_path / "card.jpg")
    pixels = _read(path)[y : y + h, x : x + w].astype(float)
    assert pixels.std(axis=(0, 1)).max() < 12  # one matte grey card: shading, noise, JPEG only
    truth, on_card = sim.square_truth(world, card, 64)
    assert 0.02 < float(on_card.float().mean()) < 0.06
    assert torch.allclose(truth.diffuse[0, :, on_card[0, 0]], torch.tensor(0.18 / 0.96), atol=1e-4)
    # the true flash in the square's units: the camera about the lens's distance above it
    scene = sim.known_scene(card)
    assert float(scene.camera.position.norm()) == pytest.approx(today.distance, rel=0.1)
    assert math.isfinite(float(scene.point_lights[0].intensity))


def test_the_benchmark_forgives_the_diffuse_level_and_nothing_else(material):
    """``shots.score``'s ``diffuse_scaled``: a diffuse off by one factor scores 0 after the best
    factor (and the factor is found), one with another pattern does not."""
    from svbrdf_render import SVBRDF

    shots = load_benchmark("shots")
    keep = torch.ones(1, 1, *material.size, dtype=torch.bool)
    dim = SVBRDF(**{**material.maps(), "diffuse": material.diffuse * 0.5})
    s = shots.score(dim, material, keep)
    assert s["diffuse"] > 0.05
    assert s["diffuse_scale"] == pytest.approx(2.0, rel=1e-4)
    assert s["diffuse_scaled"] == pytest.approx(0.0, abs=1e-5)
    flipped = SVBRDF(**{**material.maps(), "diffuse": material.diffuse.flip(-1)})
    f = shots.score(flipped, material, keep)
    assert f["diffuse_scaled"] > 0.02 and f["diffuse_scaled"] <= f["diffuse"] + 1e-6


def test_the_benchmark_reads_the_cards_flash_against_the_truth(tmp_path):
    """``shots._card_reading``: the distance across the square from the placed flash to the true
    one, and the solved intensity over the true; nothing for a capture without a reference."""
    import json

    from svbrdf_render import Camera, PointLight, Scene

    shots = load_benchmark("shots")
    known = Scene(Camera(torch.tensor([0.0, 0.0, 2.0])), (PointLight(torch.tensor([0.3, -0.4, 2.0]), 20.0),))
    record = tmp_path / "material.json"
    record.write_text(json.dumps({"reference": {"flash_intensity": 15.0, "flash_position": [0.0, 0.0, 2.1]}}))
    got = shots._card_reading(record, known)
    assert got["flash_error"] == pytest.approx(0.5, abs=1e-6)
    assert got["intensity_ratio"] == pytest.approx(0.75)
    record.write_text(json.dumps({"reference": None}))
    assert shots._card_reading(record, known) == {}
