"""Statistics of materials and photos (svbrdf_train.data.stats) on constructed cases whose values
are known, the distance between two sets, and the `svbrdf-train data compare` command."""

from __future__ import annotations

import json
import math

import pytest
import torch
from PIL import Image

from svbrdf_render import SVBRDF, write_des18, write_image
from svbrdf_train.cli import main
from svbrdf_train.data import stats

S = 32  # pixels of the constructed maps and photos


def _maps(
    b: int = 2,
    *,
    normal=(0.0, 0.0, 1.0),
    diffuse=(0.5, 0.5, 0.5),
    roughness: float = 0.5,
    specular=(0.04, 0.04, 0.04),
    size: int = S,
) -> torch.Tensor:
    """Packed uniform maps ``(b, 10, size, size)``."""
    n = torch.tensor(normal, dtype=torch.float32)
    n = n / n.norm()
    parts = [n, torch.tensor(diffuse), torch.tensor([roughness]), torch.tensor(specular)]
    v = torch.cat([p.float() for p in parts])
    return v.view(1, 10, 1, 1).expand(b, 10, size, size).contiguous()


def _centres(size: int = S) -> tuple[torch.Tensor, torch.Tensor]:
    t = (torch.arange(size, dtype=torch.float32) * 2 + 1) / size - 1
    return t.view(1, -1).expand(size, size), (-t).view(-1, 1).expand(size, size)


def _spot(cx: float, cy: float, width: float, *, size: int = 64, background: float = 0.1) -> torch.Tensor:
    """A grey photo ``(1, 3, size, size)``: ``background`` plus a Gaussian highlight at (cx, cy)."""
    x, y = _centres(size)
    peak = torch.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * width**2))
    return (background + 0.8 * peak).expand(1, 3, size, size).contiguous()


# -- statistics of maps --------------------------------------------------------------------------


def test_uniform_albedo_has_its_luminance_and_saturation():
    m = _maps(diffuse=(0.5, 0.25, 0.0))
    lum = 0.2126 * 0.5 + 0.7152 * 0.25
    assert torch.allclose(stats.diffuse_luminance(m), torch.full((2,), lum), atol=1e-6)
    assert torch.allclose(stats.diffuse_saturation(m), torch.ones(2), atol=1e-6)
    m = _maps(diffuse=(0.4, 0.2, 0.1))
    assert torch.allclose(stats.diffuse_saturation(m), torch.full((2,), 0.75), atol=1e-6)
    grey = _maps(diffuse=(0.3, 0.3, 0.3))
    assert torch.allclose(stats.diffuse_luminance(grey), torch.full((2,), 0.3), atol=1e-6)
    assert torch.equal(stats.diffuse_saturation(grey), torch.zeros(2))
    assert torch.equal(stats.diffuse_saturation(_maps(diffuse=(0.0, 0.0, 0.0))), torch.zeros(2))


def test_grey_specular_has_zero_saturation_coloured_specular_its_own():
    grey = _maps(specular=(0.05, 0.05, 0.05))
    assert torch.equal(stats.specular_saturation(grey), torch.zeros(2))
    assert torch.allclose(stats.specular_level(grey), torch.full((2,), 0.05), atol=1e-6)
    gold = _maps(specular=(1.0, 0.766, 0.336))
    assert torch.allclose(stats.specular_saturation(gold), torch.full((2,), 0.664), atol=1e-5)
    # Half the pixels coloured: the mean saturation is half.
    half = grey.clone()
    half[:, 7:10, :, : S // 2] = torch.tensor([0.8, 0.4, 0.2]).view(1, 3, 1, 1)
    assert torch.allclose(stats.specular_saturation(half), torch.full((2,), 0.75 / 2), atol=1e-6)


@pytest.mark.parametrize("degrees", [0.0, 10.0, 30.0, 60.0])
def test_a_tilted_plane_has_the_tan_of_its_tilt_as_slope(degrees):
    a = math.radians(degrees)
    m = _maps(normal=(math.sin(a) * 0.6, math.sin(a) * 0.8, math.cos(a)))
    expected = torch.full((2,), math.tan(a))
    assert torch.allclose(stats.slope_mean(m), expected, atol=1e-5)
    assert torch.allclose(stats.slope_p90(m), expected, atol=1e-5)


def test_slope_p90_sees_the_steep_tenth():
    m = _maps(b=1)
    steep = _maps(b=1, normal=(1.0, 0.0, 1.0))  # 45 degrees
    m[..., :5, :] = steep[..., :5, :]  # 5 of 32 rows: more than a tenth
    assert math.isclose(float(stats.slope_p90(m)), 1.0, abs_tol=1e-5)
    assert math.isclose(float(stats.slope_mean(m)), 5 / 32, abs_tol=1e-5)


def test_roughness_mean_and_histogram():
    m = torch.cat([_maps(b=1, roughness=0.2), _maps(b=1, roughness=0.6)])
    assert torch.allclose(stats.roughness_mean(m), torch.tensor([0.2, 0.6]), atol=1e-6)
    h = stats.roughness_histogram(m)
    assert h.counts.shape == (2, 64) and torch.allclose(h.counts.sum(dim=1), torch.ones(2))
    # The pooled distribution holds both materials alike: its median is between them.
    assert h.quantile(0.25) == pytest.approx(0.2, abs=1 / 64) and h.quantile(0.75) == pytest.approx(
        0.6, abs=1 / 64
    )
    low, high = (
        stats.roughness_histogram(_maps(roughness=0.3)),
        stats.roughness_histogram(_maps(roughness=0.5)),
    )
    assert stats.histogram_wasserstein(low, low) == 0
    assert stats.histogram_wasserstein(low, high) == pytest.approx(0.2, abs=1 / 64)


# -- statistics of photos ------------------------------------------------------------------------


@pytest.mark.parametrize("where", [(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4)])
def test_a_gaussian_highlight_is_found_at_its_offset(where):
    cx, cy = where
    photo = _spot(cx, cy, 0.08)
    pos = stats.highlight_position(photo)[0]
    assert torch.allclose(pos, torch.tensor([cx, cy]), atol=0.02)
    assert float(stats.highlight_offset(photo)[0]) == pytest.approx(math.hypot(cx, cy), abs=0.02)
    # The same in a batch, and whatever the resolution.
    both = torch.cat([photo, _spot(cx, cy, 0.08, size=128)[..., ::2, ::2]])
    assert torch.allclose(stats.highlight_offset(both), torch.full((2,), math.hypot(cx, cy)), atol=0.03)


def test_highlight_size_is_the_bright_share_of_the_photo():
    x, y = _centres(128)
    disc = ((x - 0.2) ** 2 + y**2 < 0.5**2).float()
    photo = (0.05 + 0.9 * disc).expand(1, 3, 128, 128)
    area = math.pi * 0.5**2 / 4  # the smoothing rounds the disc's edge a little inwards
    assert float(stats.highlight_size(photo)[0]) == pytest.approx(area, rel=0.08)
    assert float(stats.highlight_offset(photo)[0]) == pytest.approx(0.2, abs=0.01)
    # A sharper highlight is smaller; a uniform photo has none and sits in the centre.
    assert float(stats.highlight_size(_spot(0, 0, 0.05))[0]) < float(
        stats.highlight_size(_spot(0, 0, 0.2))[0]
    )
    flat = torch.full((1, 3, 32, 32), 0.3)
    assert float(stats.highlight_size(flat)[0]) == 0 and float(stats.highlight_offset(flat)[0]) == 0


def test_photo_brightness_is_its_luminance():
    photo = torch.zeros(1, 3, 4, 4)
    photo[..., :, :3] = torch.tensor([0.2, 0.4, 0.6]).view(1, 3, 1, 1)  # 3 of 4 columns lit
    lum = 0.2126 * 0.2 + 0.7152 * 0.4 + 0.0722 * 0.6
    assert float(stats.photo_mean(photo)[0]) == pytest.approx(0.75 * lum, abs=1e-6)
    assert float(stats.photo_median(photo)[0]) == pytest.approx(lum, abs=1e-6)


# -- the distance and the table ------------------------------------------------------------------


def test_wasserstein_is_zero_for_identical_sets_and_the_shift_for_shifted_ones():
    a = torch.tensor([0.1, 0.5, 0.2, 0.9])
    assert stats.wasserstein(a, a) == 0
    assert stats.wasserstein(a, a.flip(0)) == 0  # order does not matter
    assert stats.wasserstein(a, torch.cat([a, a])) == pytest.approx(0, abs=1e-12)  # nor the count
    assert stats.wasserstein(a, a + 0.25) == pytest.approx(0.25)
    assert stats.wasserstein(a + 0.25, a) == pytest.approx(0.25)
    assert stats.wasserstein([0.0], [0.0, 1.0]) == pytest.approx(0.5)
    assert stats.wasserstein(a, a * 2) > 0
    with pytest.raises(ValueError):
        stats.wasserstein([], a)


def test_compare_gives_one_row_per_statistic():
    m = _maps(diffuse=(0.5, 0.25, 0.0))
    first = {"input": _spot(0.3, 0, 0.1).expand(2, -1, -1, -1)[..., :32, :32], "maps": m}
    rows = stats.compare(first, first)
    assert [r.name for r in rows] == [s.name for s in stats.STATISTICS]
    assert all(r.distance == pytest.approx(0, abs=1e-12) for r in rows)
    shifted = {"input": first["input"] * 0.5, "maps": _maps(diffuse=(0.25, 0.125, 0.0))}
    by_name = {r.name: r for r in stats.compare(first, shifted)}
    lum = 0.2126 * 0.5 + 0.7152 * 0.25
    assert by_name["diffuse luminance"].distance == pytest.approx(lum / 2, abs=1e-6)
    assert by_name["diffuse saturation"].distance == pytest.approx(0, abs=1e-6)
    assert by_name["photo mean"].distance > 0
    assert by_name["highlight offset"].distance == pytest.approx(0, abs=1e-6)  # scaling moves nothing
    d = by_name["diffuse luminance"].to_dict()
    assert set(d) >= {"name", "unit", "procedural", "real", "wasserstein"}
    assert d["procedural"]["mean"] == pytest.approx(lum, abs=1e-6)


# -- the command ---------------------------------------------------------------------------------


def _run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def _strip_folder(folder, count=3, size=48):
    """Des18 strips of uniform maps: a known diffuse (0.4, 0.2, 0.1), grey specular, a plane
    tilted by 30 degrees, and a photo with a highlight at (0.25, 0)."""
    folder.mkdir(parents=True, exist_ok=True)
    a = math.radians(30)
    for i in range(count):
        maps = SVBRDF.unpack(
            _maps(
                1,
                normal=(math.sin(a), 0.0, math.cos(a)),
                diffuse=(0.4, 0.2, 0.1),
                specular=(0.05,) * 3,
                size=size,
            )
        )
        write_des18(folder / f"{i:07d};MatAXMatB;0X1.png", _spot(0.25, 0.0, 0.1, size=size), maps)
    return folder


def test_compare_command_prints_the_table_and_writes_sheet_and_json(tmp_path, capsys):
    real = _strip_folder(tmp_path / "real")
    sheet, doc = tmp_path / "sheet.png", tmp_path / "out" / "stats.json"
    code, out, err = _run(
        capsys,
        "data",
        "compare",
        str(real),
        "-n",
        "3",
        "-r",
        "24",
        "--seed",
        "2",
        "-o",
        str(sheet),
        "--json",
        str(doc),
    )
    assert code == 0, err
    rows = [line for line in out.splitlines() if line.startswith("| ")]
    assert len(rows) == 2 + len(stats.STATISTICS)
    assert "W1" in rows[0] and all(s.name in out for s in stats.STATISTICS)
    assert "Wasserstein" in out
    data = json.loads(doc.read_text())
    assert data["resolution"] == 24 and data["real"]["count"] == 3 and data["procedural"]["count"] == 3
    by_name = {s["name"]: s for s in data["statistics"]}
    assert set(by_name) == {s.name for s in stats.STATISTICS}
    real_stats = {k: v["real"]["mean"] for k, v in by_name.items()}
    assert real_stats["diffuse luminance"] == pytest.approx(
        0.2126 * 0.4 + 0.7152 * 0.2 + 0.0722 * 0.1, abs=0.01
    )
    assert real_stats["diffuse saturation"] == pytest.approx(0.75, abs=0.03)
    assert real_stats["specular saturation"] == pytest.approx(0, abs=0.01)
    assert real_stats["slope mean"] == pytest.approx(math.tan(math.radians(30)), abs=0.02)
    assert real_stats["highlight offset"] == pytest.approx(0.25, abs=0.05)
    assert len(by_name["slope mean"]["values"]["procedural"]) == 3
    image = Image.open(sheet)
    assert image.mode == "RGB" and image.width > 10 * 24 and image.height > 3 * 24
    # The same command again: the same table (procedural samples are seeded).
    code, again, _ = _run(capsys, "data", "compare", str(real), "-n", "3", "-r", "24", "--seed", "2")
    assert code == 0 and [line for line in again.splitlines() if line.startswith("| ")] == rows


def test_compare_help_says_what_the_distance_is(capsys):
    code, out, _ = _run(capsys, "data", "compare", "--help")
    assert code == 0
    assert "Wasserstein" in out and "unit" in out and "half-widths" in out


@pytest.mark.parametrize("kind", ["missing", "empty", "file", "photos"])
def test_compare_command_bad_folders_are_one_line_errors(tmp_path, capsys, kind):
    if kind == "missing":
        target = tmp_path / "nowhere"
    elif kind == "empty":
        target = tmp_path / "empty"
        target.mkdir()
    elif kind == "file":
        target = tmp_path / "strip.png"
        write_image(target, torch.rand(3, 8, 40))
    else:  # photos without ground truth
        target = tmp_path / "photos"
        write_image(target / "IMG_0001.png", torch.rand(3, 32, 32))
    code, out, err = _run(capsys, "data", "compare", str(target), "-n", "2", "-r", "16")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("svbrdf-train: error:") and str(target) in lines[0]
    if kind == "photos":
        assert "ground truth" in lines[0]


@pytest.mark.data
def test_compare_on_des18_dev(shared_data, tmp_path, capsys):
    folder = shared_data / "des18-dev"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    doc = tmp_path / "stats.json"
    code, out, err = _run(capsys, "data", "compare", str(folder), "-n", "8", "-r", "64", "--json", str(doc))
    assert code == 0, err
    data = json.loads(doc.read_text())
    assert data["real"]["count"] == 21
    by_name = {s["name"]: s for s in data["statistics"]}
    # Des18's photos: the flash fitted to them sits 0.08-0.30 half-widths off the centre.
    offset = by_name["highlight offset"]["real"]
    assert 0.1 < offset["mean"] < 0.3
    assert all(math.isfinite(s["wasserstein"]) and s["wasserstein"] >= 0 for s in data["statistics"])
