"""benchmarks/phone_capture.py: its photo statistics read what the capture effects do to a photo
(a moved highlight, a nearer flash, vignetting, overexposure, a colour cast, JPEG blocks), its
distance between distributions is the Kolmogorov-Smirnov statistic, and bad input is a one-line
error."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_benchmark

SIZE = 64


@pytest.fixture(scope="module")
def pc():
    return load_benchmark("phone_capture")


def flash_photo(at=(0.0, 0.0), distance=2.3, level=0.5, gains=(1.0, 1.0, 1.0)) -> torch.Tensor:
    """A grey patch under a flash at ``distance`` over the point ``at`` (half-widths, x right,
    y down): the point light's ``cos^3 / d^2`` fall-off plus a narrow specular peak."""
    g = (np.arange(SIZE) + 0.5) / (SIZE / 2) - 1
    y, x = np.meshgrid(g, g, indexing="ij")
    r2 = (x - at[0]) ** 2 + (y - at[1]) ** 2
    lum = level * (distance**2 / (distance**2 + r2)) ** 1.5 + 0.3 * np.exp(-r2 / 0.01)
    photo = np.stack([lum * k for k in gains]).clip(0, 1)
    return torch.from_numpy(photo.astype(np.float32))


def vignette(photo: torch.Tensor, strength: float = 1.0) -> torch.Tensor:
    g = (torch.arange(SIZE) + 0.5) / (SIZE / 2) - 1
    y, x = torch.meshgrid(g, g, indexing="ij")
    cos4 = (1 / (1 + (x**2 + y**2) / 2.3**2)) ** 2
    return photo * (1 - strength + strength * cos4)


def test_a_moved_highlight_is_farther_from_the_centre(pc):
    centred = pc.photo_stats(flash_photo())["highlight"]
    moved = pc.photo_stats(flash_photo(at=(0.5, -0.3)))["highlight"]
    assert centred < 0.1 and moved == pytest.approx(np.hypot(0.5, 0.3), abs=0.08)


def test_a_nearer_flash_falls_off_faster_and_vignetting_darkens_the_corners(pc):
    far, near = pc.photo_stats(flash_photo(distance=3.5)), pc.photo_stats(flash_photo(distance=1.5))
    assert near["fall 1.0"] < near["fall 0.5"] < 1 and near["fall 1.0"] < far["fall 1.0"] - 0.1
    plain = pc.photo_stats(flash_photo())
    dark = pc.photo_stats(vignette(flash_photo()))
    assert dark["corners"] < plain["corners"] - 0.1 and dark["fall 1.0"] < plain["fall 1.0"]
    assert dark["highlight"] == plain["highlight"]


def test_overexposure_clips_and_a_cast_shows_in_the_channel_ratios(pc):
    plain, bright = pc.photo_stats(flash_photo()), pc.photo_stats(flash_photo(level=1.2))
    assert plain["clipped"] == 0 and bright["clipped"] > 0.3 and bright["level"] > plain["level"]
    warm = pc.photo_stats(flash_photo(gains=(1.2, 1.0, 0.9)))
    assert plain["R/G"] == pytest.approx(1) and plain["B/G"] == pytest.approx(1)
    assert warm["R/G"] == pytest.approx(1.2, rel=1e-3) and warm["B/G"] == pytest.approx(0.9, rel=1e-3)


def test_jpeg_sized_blocks_raise_the_blockiness(pc):
    rng = np.random.default_rng(0)
    grain = torch.from_numpy(rng.uniform(-0.02, 0.02, (SIZE, SIZE))).float()  # texture, noise
    textured = (flash_photo() + grain).clamp(0, 1)
    steps = torch.from_numpy(rng.uniform(-0.05, 0.05, (SIZE // 8, SIZE // 8))).float()
    blocky = (textured + steps.repeat_interleave(8, 0).repeat_interleave(8, 1)).clamp(0, 1)
    assert pc.photo_stats(textured)["blocks"] == pytest.approx(1, abs=0.1)
    assert pc.photo_stats(blocky)["blocks"] > 1.5


def test_the_distance_is_the_kolmogorov_smirnov_statistic(pc):
    a = np.array([1.0, 2.0, 3.0, 4.0])
    assert pc.ks_distance(a, a) == 0 and pc.ks_distance(a, a + 10) == 1
    assert pc.ks_distance(a, np.array([2.5, 3.5, 4.5, 5.5, np.nan])) == pytest.approx(0.5)


def test_removing_an_effect_that_matched_the_real_photos_says_keep(pc):
    rng = np.random.default_rng(1)
    real = rng.normal(1.0, 0.1, (21, len(pc.STATS)))
    base = rng.normal(1.0, 0.1, (40, len(pc.STATS)))
    without = base.copy()
    without[:, pc.STATS.index("corners")] += 0.3  # without the effect the corners are off
    delta, support = pc.effect_change(real, base, without, ("corners",), np.random.default_rng(0))
    assert delta > 0.5 and support > pc.SUPPORT and pc.verdict(delta, support).startswith("keep")
    delta, support = pc.effect_change(real, without, base, ("corners",), np.random.default_rng(0))
    assert delta < -0.5 and pc.verdict(delta, support).startswith("drop")
    assert pc.verdict(*pc.effect_change(real, base, base, ("corners",))) == "no change on these statistics"


def test_a_missing_folder_or_no_photos_is_a_one_line_error(pc, tmp_path, capsys):
    for folder in (tmp_path / "absent", tmp_path):
        with pytest.raises(SystemExit) as e:
            pc.main([str(folder), "--strips", str(tmp_path)])
        err = capsys.readouterr().err.strip()
        assert e.value.code == 2 and len(err.splitlines()) == 1 and err.startswith("phone_capture: error:")


def test_a_missing_strips_folder_is_a_one_line_error(pc, tmp_path, capsys):
    from svbrdf_render import write_image

    write_image(tmp_path / "photos" / "one.png", flash_photo())
    with pytest.raises(SystemExit) as e:
        pc.main([str(tmp_path / "photos"), "--strips", str(tmp_path / "absent"), "--size", "64"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1 and "absent" in err
