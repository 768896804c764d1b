"""The printed capture frame (``svbrdf-models frame``, :mod:`svbrdf_models.capture.frame`): the
sheet is drawn at its true size, and in a synthetic photo of it, taken by a camera of known pose
and focal length, the markers are found, the camera and the flash are recovered, and the window
comes back upright whatever the photo's roll."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from shotphotos import look_at as _look_at  # a camera at a point looking at the window (shared)

from svbrdf_models.capture.frame import MIN_MARKERS, PAPERS, FrameLayout, draw_frame
from svbrdf_models.capture.framephoto import find_frame, rectify, shot_pose
from svbrdf_models.cli import main
from svbrdf_models.errors import DataError

cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (svbrdf-models[photo]) is not installed")

DPI = 150
#: The colours pasted in the window's quadrants: top-left, top-right, bottom-left, bottom-right.
QUADRANTS = {"tl": (230, 40, 40), "tr": (40, 200, 40), "bl": (40, 40, 220), "br": (230, 230, 40)}


def _page_with_pattern(layout: FrameLayout, dpi: int = DPI) -> np.ndarray:
    """The drawn sheet (RGB) with a coloured quadrant pattern in the window."""
    page = np.array(draw_frame(layout, dpi).convert("RGB"))
    scale = dpi / 2.54
    ox, oy = layout.origin_on_page_cm
    half = layout.half_width_cm
    left, right = round((ox - half) * scale), round((ox + half) * scale)
    top, bottom = round((oy - half) * scale), round((oy + half) * scale)
    mx, my = (left + right) // 2, (top + bottom) // 2
    page[top:my, left:mx] = QUADRANTS["tl"]
    page[top:my, mx:right] = QUADRANTS["tr"]
    page[my:bottom, left:mx] = QUADRANTS["bl"]
    page[my:bottom, mx:right] = QUADRANTS["br"]
    return page


def _photo(
    layout, camera_cm, focal=1100.0, size=(1280, 960), up=(0.0, 1.0, 0.0), *, jpeg=90, seed=0, page=None
):
    """A synthetic photo (H, W, 3 uint8) of the sheet lying on a textured table, by a pinhole
    camera at ``camera_cm`` (frame cm), with noise and JPEG compression."""
    w, h = size
    rot, t = _look_at(camera_cm, up)
    k = np.array([[focal, 0, (w - 1) / 2], [0, focal, (h - 1) / 2], [0, 0, 1]])
    frame_to_photo = k @ np.column_stack([rot[:, 0], rot[:, 1], t])
    scale = DPI / 2.54
    ox, oy = layout.origin_on_page_cm
    # page pixel (u, v) (centre at integers) -> frame cm
    page_to_frame = np.array([[1 / scale, 0, 0.5 / scale - ox], [0, -1 / scale, oy - 0.5 / scale], [0, 0, 1]])
    ss = 2  # supersample, then area-average: no aliasing of the markers
    up2 = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1]])
    page = _page_with_pattern(layout) if page is None else page
    rng = np.random.default_rng(seed)
    table = rng.integers(60, 120, size=(h * ss // 8, w * ss // 8, 3), dtype=np.uint8)
    table = cv2.resize(table, (w * ss, h * ss), interpolation=cv2.INTER_LINEAR)
    warped = cv2.warpPerspective(page, up2 @ frame_to_photo @ page_to_frame, (w * ss, h * ss))
    mask = cv2.warpPerspective(
        np.full(page.shape[:2], 255, np.uint8), up2 @ frame_to_photo @ page_to_frame, (w * ss, h * ss)
    )
    big = np.where(mask[..., None] > 127, warped, table)
    photo = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    photo = np.clip(photo * 0.85 + rng.normal(0, 3, photo.shape), 0, 255).astype(np.uint8)
    ok, data = cv2.imencode(".jpg", photo[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, jpeg])
    return cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1].copy()


@pytest.fixture(scope="module")
def layout():
    return FrameLayout()


@pytest.fixture(scope="module")
def page(layout):
    return _page_with_pattern(layout)


def test_layout_is_one_declaration_with_distinct_ids_per_window():
    a, b = FrameLayout(window_cm=10), FrameLayout(window_cm=8)
    assert len(a.marker_ids) == 8 and not set(a.marker_ids) & set(b.marker_ids)
    assert all(FrameLayout.window_of_id(i) == 10 for i in a.marker_ids)
    assert FrameLayout(window_cm=10, paper="letter").marker_ids == a.marker_ids  # the paper moves nothing
    # the markers surround the window, clear of it by the gap; the strip is under them
    corners = a.marker_corners.reshape(-1, 2)
    assert np.abs(corners).max(axis=1).min() == pytest.approx(a.half_width_cm + a.gap_cm)
    x0, y0, x1, y1 = a.strip_rect
    assert y1 < corners[:, 1].min() and x1 - x0 > a.window_cm
    with pytest.raises(DataError, match="steps of 0.5"):
        FrameLayout(window_cm=10.2)
    with pytest.raises(DataError, match="does not fit on letter paper.*: at most 13 cm"):
        FrameLayout(window_cm=14, paper="letter")
    FrameLayout(window_cm=14, paper="a4")


def test_find_frame_pose_and_rectify_from_an_oblique_photo(layout, page):
    camera = np.array([4.0, -6.0, 28.0])  # cm, off to the side and below, the sheet tilted in view
    photo = _photo(layout, camera, page=page)
    found = find_frame(photo, layout, name="shot1.jpg")
    assert sorted(found.ids.tolist()) == list(layout.marker_ids)
    assert found.rms_px < 0.5  # sub-pixel corners under JPEG and noise
    pose = shot_pose(found, 1100.0, flash_offset_cm=(0.0, 0.0))
    truth = torch.tensor(camera / layout.half_width_cm, dtype=torch.float32)
    assert torch.linalg.norm(pose.camera - truth) / torch.linalg.norm(truth) < 0.02, (pose.camera, truth)
    assert pose.camera[2] > 0  # +z towards the camera
    # the flash, 1 cm to the right of the lens as the photo shows it: along the camera's x axis
    offset = shot_pose(found, 1100.0, flash_offset_cm=(1.0, 0.0))
    step = (offset.flash - offset.camera) * layout.half_width_cm
    assert torch.allclose(step, offset.rotation[:, 0], atol=1e-4) and step.norm() == pytest.approx(
        1.0, abs=1e-4
    )
    assert torch.allclose(pose.flash, pose.camera, atol=1e-5)
    rectified = rectify(photo, found, 64)
    _assert_upright(rectified.window)
    # the boundary between the top quadrants (red | green) lands on the square's middle column
    fine = rectify(photo, found, 256).window
    green = fine[1, 20:100].mean(dim=0)  # along x, in the top half
    crossing = int(torch.nonzero(green > (green[:60].mean() + green[-60:].mean()) / 2)[0])
    assert abs(crossing - 128) <= 1, crossing
    assert rectified.strip.shape[0] == 3 and rectified.strip.shape[1:] == rectified.strip_xy.shape[1:]
    assert rectified.strip.mean() > 0.7  # the paper, not the markers or the table
    x0, y0, x1, y1 = (v / layout.half_width_cm for v in layout.strip_rect)
    assert x0 < rectified.strip_xy[0].min() < rectified.strip_xy[0].max() < x1
    assert y0 < rectified.strip_xy[1].min() < rectified.strip_xy[1].max() < y1


def _assert_upright(window: torch.Tensor):
    """The quadrant colours came back where they were pasted (top row = y = +1)."""
    assert window.shape[0] == 3 and window.shape[1] == window.shape[2]
    window = torch.nn.functional.interpolate(window[None], size=64, mode="area")[0]
    quads = {
        "tl": window[:, 4:28, 4:28],
        "tr": window[:, 4:28, 36:60],
        "bl": window[:, 36:60, 4:28],
        "br": window[:, 36:60, 36:60],
    }
    for key, colour in QUADRANTS.items():
        mean = quads[key].mean(dim=(1, 2))
        expected = torch.tensor(colour, dtype=torch.float32) / 255 * 0.85
        assert torch.allclose(mean, expected, atol=0.05), (key, mean, expected)


def test_a_photo_rolled_90_degrees_rectifies_upright_and_linear_tensors_work(layout, page):
    camera = np.array([-3.0, 2.0, 30.0])
    photo = _photo(layout, camera, up=(1.0, 0.0, 0.0), page=page, seed=1)  # the frame's x shown up
    linear = torch.from_numpy(photo).permute(2, 0, 1).float().div(255).pow(2.2)  # (3, H, W) linear
    found = find_frame(linear, layout, linear=True)
    assert len(found.ids) == 8
    rectified = rectify(linear.pow(1 / 2.2), found, 64)  # the window ~360 px: area-averaged first
    _assert_upright(rectified.window)
    _assert_upright(rectify(photo, found, 256).window)  # warped directly
    pose = shot_pose(found, 1100.0)
    truth = torch.tensor(camera / layout.half_width_cm, dtype=torch.float32)
    assert torch.linalg.norm(pose.camera - truth) / torch.linalg.norm(truth) < 0.02


def test_covered_markers_still_found_down_to_the_minimum(layout, page):
    camera = np.array([0.0, 0.0, 32.0])
    photo = _photo(layout, camera, page=page, seed=2)
    found = find_frame(photo, layout)
    # cover markers one by one with a "hand" (a flat patch over each marker's pixels)
    covered = photo.copy()
    order = list(found.ids)
    for n, marker_id in enumerate(order[: len(order) - MIN_MARKERS + 1], start=1):
        quad = found.corners[list(found.ids).index(marker_id)]
        cv2.fillConvexPoly(covered, np.round(_grow(quad, 1.3)).astype(np.int32), (150, 120, 100))
        if len(order) - n >= MIN_MARKERS:
            assert len(find_frame(covered, layout).ids) == len(order) - n
        else:
            with pytest.raises(
                DataError, match=rf"frame not found in hand.jpg: {MIN_MARKERS - 1} markers of 8 seen"
            ):
                find_frame(covered, layout, name="hand.jpg")


def _grow(quad, factor):
    centre = quad.mean(axis=0)
    return centre + (quad - centre) * factor


def test_a_photo_without_the_frame_is_refused_naming_it():
    rng = np.random.default_rng(3)
    texture = cv2.resize(
        rng.integers(0, 255, (60, 80, 3), dtype=np.uint8), (800, 600), interpolation=cv2.INTER_NEAREST
    )
    with pytest.raises(DataError) as e:
        find_frame(texture, FrameLayout(), name="noframe.jpg")
    message = str(e.value)
    assert message.startswith("frame not found in noframe.jpg: 0 markers of 8 seen") and "\n" not in message
    with pytest.raises(DataError, match="frame not found in noframe.jpg: no marker"):
        find_frame(texture, name="noframe.jpg")


def test_markers_of_another_frame_are_recognised():
    other = FrameLayout(window_cm=8)
    photo = _photo(other, np.array([1.0, 1.0, 26.0]), seed=4)
    with pytest.raises(DataError, match="markers of another frame in shot2.jpg: 8 markers of the 8 cm frame"):
        find_frame(photo, FrameLayout(window_cm=10), name="shot2.jpg")
    found = find_frame(photo)  # no layout given: the markers say which frame it is
    assert found.layout.window_cm == 8 and len(found.ids) == 8


def test_importing_the_frame_and_the_command_line_loads_neither_opencv_nor_pillow():
    import subprocess
    import sys

    code = (
        "import sys, svbrdf_models.cli, svbrdf_models.capture.frame, svbrdf_models.capture.framephoto\n"
        "print(','.join(m for m in ('cv2', 'PIL') if m in sys.modules))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""


def test_opencv_comes_with_the_photo_extra_only():
    from importlib.metadata import requires

    render = [r for r in requires("svbrdf-render") or [] if "opencv" in r]
    models = [r for r in requires("svbrdf-models") or [] if "opencv" in r]
    assert render == [] and len(models) == 1 and models[0].endswith('extra == "photo"'), models


def test_missing_opencv_says_how_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(DataError, match=re.escape("pip install 'svbrdf-models[photo]'")):
        find_frame(np.zeros((64, 64, 3), np.uint8))


# --- the command ------------------------------------------------------------------------------
@pytest.mark.parametrize("paper", ["a4", "letter"])
def test_frame_command_writes_a_pdf_at_the_papers_size(paper, tmp_path, capsys):
    out = tmp_path / "frame.pdf"
    assert main(["frame", "-o", str(out), "--paper", paper, "--dpi", "150"]) == 0
    data = out.read_bytes()
    box = [float(v) for v in re.search(rb"/MediaBox \[ *([\d. ]+)\]", data).group(1).split()]
    width_cm, height_cm = PAPERS[paper]
    assert box[2] == pytest.approx(width_cm / 2.54 * 72, abs=0.5)  # points, within a pixel at 150 dpi
    assert box[3] == pytest.approx(height_cm / 2.54 * 72, abs=0.5)
    assert str(out) in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["frame.pdf"]  # no temporary left


def test_frame_command_writes_a_png_at_dpi_and_it_is_found_again(tmp_path):
    from PIL import Image

    out = tmp_path / "frame.png"
    assert main(["frame", "-o", str(out), "--window-cm", "6", "--paper", "letter", "--dpi", "100"]) == 0
    with Image.open(out) as image:
        assert image.size == (round(21.59 / 2.54 * 100), round(27.94 / 2.54 * 100))
        assert image.info["dpi"] == pytest.approx((100, 100), abs=0.01)
        sheet = np.array(image.convert("RGB"))
    found = find_frame(sheet)  # the file itself, seen straight on
    assert found.layout.window_cm == 6 and len(found.ids) == 8
    side = np.linalg.norm(found.window[1] - found.window[0])
    assert side == pytest.approx(6 / 2.54 * 100, abs=1.0)  # the window is 6 cm at 100 dpi


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["frame", "-o", "frame.svg"], "not '.svg'"),
        (["frame", "-o", "frame.pdf", "--window-cm", "10.3"], "steps of 0.5 cm"),
        (["frame", "-o", "frame.pdf", "--window-cm", "14", "--paper", "letter"], "at most 13 cm"),
        (["frame", "-o", "frame.pdf", "--paper", "a3"], "--paper"),
        (["frame", "-o", "frame.pdf", "--dpi", "10"], "--dpi"),
        (["frame"], "-o"),
    ],
)
def test_frame_command_bad_input_is_one_line_exit_2(argv, fragment, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("svbrdf-models") and err.count("\n") == 1 and fragment in err, err
    assert list(tmp_path.iterdir()) == []


def test_frame_command_unwritable_output_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["frame", "-o", str(tmp_path / "file" / "frame.pdf"), "--dpi", "72"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "frame.pdf" in err and "a file is in the way" in err


def test_frame_help_teaches_the_capture(capsys):
    assert main(["frame", "--help"]) == 0
    out = capsys.readouterr().out
    for word in ("100%", "ruler", "cut out", "flat", "albedo", "--window-cm"):
        assert word in out, word
