"""Where the camera stood, from the photo (issue 44): svbrdf_models.capture.geometry reads the
lens from EXIF (35 mm equivalent, else focal length and sensor) or --fov / --distance, accounts
for the EXIF orientation and the square captured (--crop), and the refinement's camera and
flash stand there; material.json says which geometry was used and from where. A photo without
EXIF and without the flags is captured exactly as before.

Photos are small (64-128 px) renderings of a known material written with Pillow, EXIF set
through ``PIL.Image.Exif``; refinements are a few eager steps; the predictor is a stand-in
that answers known maps.
"""

from __future__ import annotations

import json
import math

import pytest
import torch
from PIL import Image

from svbrdf_models.capture.geometry import DIAGONAL_35MM, capture_geometry, check_distance, check_fov
from svbrdf_models.capture.one import CaptureOptions, capture_one
from svbrdf_models.capture.refining import refine_prediction
from svbrdf_models.cli import main
from svbrdf_models.errors import DataError
from svbrdf_render import Scene, render
from svbrdf_render.examples import example_material
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_render.refinement.fit import axis_flash

EXIF_IFD, ORIENTATION = 0x8769, 0x0112
FOCAL_35MM, FOCAL_LENGTH, PLANE_X, PLANE_UNIT, PIXEL_X = 0xA405, 0x920A, 0xA20E, 0xA210, 0xA002


class _Known:
    """A stand-in predictor that always answers the same maps."""

    def __init__(self, resolution: int = 64):
        self.resolution = resolution
        self.maps = example_material("tiles", resolution)
        self.source, self.sha256, self.steps = "known:tiles", "0" * 64, 0

    def predict(self, photo):
        return self.maps


def _pixels(width: int, height: int):
    """An sRGB flash photo of a known material, ``width x height``, as a Pillow image."""
    maps = example_material("tiles", max(width, height))
    photo = render(maps, Scene.flash(intensity=12.0)).clamp(0, 1)[0][:, :height, :width]
    data = (linear_to_srgb(photo) * 255).round().byte().permute(1, 2, 0).contiguous().numpy()
    return Image.fromarray(data)


def _jpeg(path, ifd: dict, width=128, height=96, orientation=None):
    """A JPEG of ``width x height`` stored pixels with the Exif IFD tags ``ifd`` (tag id -> value)."""
    exif = Image.Exif()
    if orientation is not None:
        exif[ORIENTATION] = orientation
    exif.get_ifd(EXIF_IFD).update(ifd)
    _pixels(width, height).save(path, format="JPEG", quality=95, exif=exif)
    return path


def _f35(path, f35=26, **kw):
    return _jpeg(path, {FOCAL_35MM: f35, FOCAL_LENGTH: 4.2}, **kw)


# -- reading the lens ----------------------------------------------------------------------------


def test_exif_35mm_focal_length_gives_the_distance_of_the_centred_square(tmp_path):
    """26 mm equivalent on a 128x96 photo: f_px = 26 * hypot(128, 96) / 43.27; the centred 96 px
    square has the camera on its axis at f_px / 48 (a phone's main camera: about 2.0)."""
    g = capture_geometry(_f35(tmp_path / "a.jpg"))
    f_px = 26 * math.hypot(128, 96) / DIAGONAL_35MM
    assert g.source == "exif-35mm" and g.focal_35mm == 26 and g.focal_mm == pytest.approx(4.2)
    assert g.focal_px == pytest.approx(f_px)
    assert g.position == pytest.approx((0.0, 0.0, f_px / 48))
    assert g.position[2] == pytest.approx(2.003, abs=1e-3)
    assert g.fov == pytest.approx(math.degrees(2 * math.atan(64 / f_px)))
    assert g.photo_size == (128, 96) and g.square == (16, 0, 96)


def test_exif_sensor_route_focal_length_times_pixel_density(tmp_path):
    """No 35 mm equivalent: focal length (mm) times FocalPlaneXResolution (per unit: mm, inch by
    default), scaled when the photo was resized after the camera wrote it (PixelXDimension)."""
    mm = _jpeg(tmp_path / "mm.jpg", {FOCAL_LENGTH: 4.0, PLANE_X: 25.0, PLANE_UNIT: 4})
    g = capture_geometry(mm)
    assert g.source == "exif-sensor" and g.focal_px == pytest.approx(100.0)
    assert g.position == pytest.approx((0.0, 0.0, 100 / 48))
    inch = _jpeg(tmp_path / "inch.jpg", {FOCAL_LENGTH: 4.0, PLANE_X: 635.0})  # no unit: inch
    assert capture_geometry(inch).focal_px == pytest.approx(4.0 * 635 / 25.4)
    resized = _jpeg(tmp_path / "half.jpg", {FOCAL_LENGTH: 4.0, PLANE_X: 50.0, PLANE_UNIT: 4, PIXEL_X: 256})
    assert capture_geometry(resized).focal_px == pytest.approx(100.0)  # 200 px at 256 wide, 128 now
    none = _jpeg(tmp_path / "none.jpg", {FOCAL_LENGTH: 4.0})  # a focal length alone: no scale
    assert capture_geometry(none).source == "default"


def test_orientation_crop_is_in_displayed_pixels(tmp_path):
    """Stored 128x96 with orientation 6 (a quarter turn): displayed 96x128. A crop at the top
    left of the displayed photo has the camera right of and below the square's centre."""
    g = capture_geometry(_f35(tmp_path / "turned.jpg", orientation=6), (0, 0, 64))
    f_px = 26 * math.hypot(128, 96) / DIAGONAL_35MM
    assert g.photo_size == (96, 128) and g.square == (0, 0, 64)
    assert g.position == pytest.approx(((48 - 32) / 32, -(64 - 32) / 32, f_px / 32))
    assert g.fov == pytest.approx(math.degrees(2 * math.atan(64 / f_px)))  # the longer side, either way


def test_a_crop_moves_the_camera_away_and_to_the_side(tmp_path):
    """The centred square has the camera on its axis; a smaller crop narrows the field of view
    (farther, in its own half-widths); an off-centre crop has the camera toward the photo's centre."""
    path = _f35(tmp_path / "a.jpg")
    full = capture_geometry(path)
    centred = capture_geometry(path, (32, 16, 64))
    top_left, bottom_right = capture_geometry(path, (0, 0, 64)), capture_geometry(path, (64, 32, 64))
    assert full.position[:2] == (0.0, 0.0) and centred.position[:2] == (0.0, 0.0)
    assert centred.position[2] == pytest.approx(full.position[2] * 96 / 64)
    assert top_left.position[0] > 0 and top_left.position[1] < 0  # camera right of it, below it
    assert bottom_right.position[0] < 0 and bottom_right.position[1] > 0
    assert top_left.position[:2] == pytest.approx((1.0, -0.5)) and top_left.distance > centred.distance


def test_fov_and_distance_flags(tmp_path):
    """--fov: across the longer side as displayed, over EXIF; --distance: the height over the
    square's centre, whatever the crop."""
    path = _f35(tmp_path / "a.jpg")
    g = capture_geometry(path, fov=60)
    f_px = 64 / math.tan(math.radians(30))
    assert g.source == "fov" and g.fov == 60 and g.focal_px == pytest.approx(f_px)
    assert g.position == pytest.approx((0.0, 0.0, f_px / 48))
    assert capture_geometry(path, (0, 0, 64), fov=60).position == pytest.approx((1.0, -0.5, f_px / 32))
    d = capture_geometry(path, (0, 0, 64), distance=3.5)
    assert d.source == "distance" and d.position == (0.0, 0.0, 3.5) and d.focal_px is None
    plain = tmp_path / "plain.png"
    _pixels(128, 96).save(plain)
    assert capture_geometry(plain).source == "default"
    assert capture_geometry(plain).position == (0.0, 0.0, 2.2)
    assert capture_geometry(plain, fov=60).position == pytest.approx(g.position)


@pytest.mark.parametrize("fov", [0.5, 1, 179, 200, -10, float("nan"), float("inf"), "wide", True])
def test_fov_outside_1_179_is_refused(fov):
    with pytest.raises(DataError, match=r"--fov .*between 1 and 179"):
        check_fov(fov)
    with pytest.raises(DataError, match="--fov"):
        CaptureOptions(fov=fov)


@pytest.mark.parametrize("distance", [0, -1, float("nan"), float("inf"), "far"])
def test_distance_not_a_positive_number_is_refused(distance):
    with pytest.raises(DataError, match=r"--distance .*finite number > 0"):
        check_distance(distance)
    with pytest.raises(DataError, match="--distance"):
        CaptureOptions(distance=distance)


def test_fov_with_distance_or_scene_is_refused():
    with pytest.raises(DataError, match="--fov 60 and --distance 2"):
        CaptureOptions(fov=60, distance=2)
    with pytest.raises(DataError, match="--distance and --scene"):
        CaptureOptions(distance=2, refine=2, scene=Scene.flash(2.2, 10.0))


# -- the command line ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, says",
    [
        (["--fov", "200"], "--fov 200.0: the field of view"),
        (["--fov", "1"], "between 1 and 179"),
        (["--fov", "nan"], "--fov nan"),
        (["--fov", "wide"], "argument --fov: invalid float value: 'wide'"),
        (["--distance", "0"], "--distance 0.0: the camera's height must be a finite number > 0"),
        (["--distance", "-2"], "--distance -2.0"),
        (["--fov", "60", "--distance", "2"], "--fov 60.0 and --distance 2.0: give one"),
    ],
)
def test_command_bad_geometry_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, args, says):
    photo = _f35(tmp_path / "a.jpg")
    code = main(["predict", str(photo), "-o", str(tmp_path / "maps"), *args])
    err = capsys.readouterr().err
    assert code == 2 and says in err, err
    assert err.startswith("svbrdf-models") and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "maps").exists()


def test_command_help_teaches_fov_and_distance(capsys):
    assert main(["predict", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--fov DEG" in text and "--distance D" in text
    assert "longer side" in text and "EXIF" in text and "half-widths of the square" in text


# -- the capture ---------------------------------------------------------------------------------


def test_refinement_stands_at_the_photos_geometry_and_material_json_says_so(tmp_path):
    """An EXIF photo with a crop: the refinement's camera and flash at the geometry's height (not
    2.2), where the fall-off of the photo's light puts the flash (a flash beside the lens: where
    a tilted phone was), searched around the geometry's x and y; material.json's geometry
    section gives the place, where it came from and how well the fall-off fitted."""
    from svbrdf_render.refinement.falloff import fall_off_point

    path = _f35(tmp_path / "shot.jpg")
    options = CaptureOptions(refine=2, relit="none", crop=(0, 0, 64))
    entry = capture_one(_Known(), path, tmp_path / "out", options)
    want = list(capture_geometry(path, (0, 0, 64)).position)
    from svbrdf_models.capture.photos import load_photo

    square = load_photo(path, crop=(0, 0, 64))[0][None]  # the capture's square
    point, misfit = fall_off_point(square, want[2], around=torch.tensor(want[:2]))
    distance = math.hypot(*want)  # the lens's distance to the square's centre, kept
    want[:2] = [float(v) for v in point[0]]
    want[2] = math.sqrt(distance**2 - want[0] ** 2 - want[1] ** 2)
    assert entry["flash"]["position"] == pytest.approx(want, abs=1e-5)
    record = json.loads((tmp_path / "out" / "material.json").read_text())
    geometry = record["geometry"]
    assert geometry["source"] == "exif-35mm" and geometry["used"] is True and geometry["over"] == "fall-off"
    assert geometry["fall_off_misfit"] == pytest.approx(float(misfit[0]), abs=1e-4)
    assert record["flash"]["placed"] == "fall-off"
    assert geometry["position"] == pytest.approx(list(want), abs=1e-4)
    assert geometry["distance"] == pytest.approx(distance, abs=1e-4)
    assert geometry["focal_length_35mm"] == 26 and geometry["focal_length_mm"] == pytest.approx(4.2)
    assert geometry["photo_size"] == [128, 96] and geometry["square"] == [0, 0, 64]
    f_px = 26 * math.hypot(128, 96) / DIAGONAL_35MM
    assert geometry["fov"] == pytest.approx(math.degrees(2 * math.atan(64 / f_px)), abs=1e-3)


def test_network_maps_only_record_the_geometry_unused(tmp_path):
    path = _f35(tmp_path / "shot.jpg")
    capture_one(_Known(), path, tmp_path / "out", CaptureOptions(relit="none", distance=3.0))
    geometry = json.loads((tmp_path / "out" / "material.json").read_text())["geometry"]
    assert geometry["source"] == "distance" and geometry["position"] == [0.0, 0.0, 3.0]
    assert geometry["used"] is False  # --refine 0: the flash is fitted to the network's maps


def test_a_photo_without_exif_or_flags_keeps_todays_maps(tmp_path, refine_calls):
    """No EXIF, no --fov or --distance: the refinement is today's call (no camera: the flash at
    2.2 over the highlight), and its maps are identical to that call's; material.json says
    "default"."""
    path = tmp_path / "plain.png"
    _pixels(96, 96).save(path)
    entry = capture_one(_Known(), path, tmp_path / "out", CaptureOptions(refine=3, relit="none"))
    (photo, start, steps, kw, got), = refine_calls
    assert kw.get("camera") is None
    old = refine_prediction(photo, start, steps, seconds=None, scene=None, backend=kw["backend"])
    for name, want in old.svbrdf.maps().items():
        assert torch.equal(getattr(got.svbrdf, name), want), name
    assert entry["flash"]["position"][2] == pytest.approx(2.2)
    geometry = json.loads((tmp_path / "out" / "material.json").read_text())["geometry"]
    assert geometry["source"] == "default" and geometry["position"] is None
    assert geometry["distance"] == pytest.approx(2.2) and geometry["over"] == "highlight"


def test_refine_prediction_camera_and_axis_flash_position():
    """axis_flash(position=) is axis_flash(over=, distance=) for the same point; refine_prediction(
    camera=) puts the scene's camera and light there."""
    maps = example_material("tiles", 64)
    photo = render(maps, Scene.flash(intensity=12.0)).clamp(0, 1)
    over = axis_flash(maps, photo, distance=3.0, over=torch.tensor([[0.25, -0.5]]))
    at = axis_flash(maps, photo, position=torch.tensor([0.25, -0.5, 3.0]))
    assert torch.equal(over.point_lights[0].position, at.point_lights[0].position)
    k = [torch.as_tensor(scene.point_lights[0].intensity) for scene in (over, at)]
    assert torch.equal(*k)
    result = refine_prediction(photo, maps, 1, camera=torch.tensor([0.5, 0.25, 3.0]), backend="eager")
    light = result.scene.point_lights[0]
    assert light.position.reshape(-1, 3)[0].tolist() == pytest.approx([0.5, 0.25, 3.0])
    assert result.scene.camera.position.reshape(-1, 3)[0].tolist() == pytest.approx([0.5, 0.25, 3.0])


@pytest.mark.parametrize("roughness", [0.3, 0.9])
def test_a_tilted_phone_s_flash_stands_where_its_light_falls_off_from(tmp_path, roughness):
    """A photo whose flash stood 0.3 half-widths right of and 0.2 below the square's centre (a
    phone held off-centre or tilted): with the lens from EXIF the flash is placed where the
    fall-off of its light puts it, at the height the lens gives, not on the square's axis, on a
    glossy material and on a matte one that shows no clear highlight (which used to leave the
    flash on the axis); ``--distance`` keeps the axis the user states."""
    from svbrdf_render.refinement.fit import flash_scene
    from svbrdf_render.refinement.rings import find_highlight

    from svbrdf_render import SVBRDF

    maps = SVBRDF.constant(1, 96, diffuse=(0.2, 0.2, 0.2), roughness=roughness, specular=(0.04, 0.04, 0.04))
    photo = render(maps, flash_scene(torch.tensor([[0.3, -0.2, 2.0]]), torch.tensor([10.0]))).clamp(0, 1)[0]
    assert bool(find_highlight(photo[None])[1][0]) is (roughness < 0.5)
    data = (linear_to_srgb(photo) * 255).round().byte().permute(1, 2, 0).contiguous().numpy()
    exif = Image.Exif()
    exif.get_ifd(EXIF_IFD).update({FOCAL_35MM: 26})
    path = tmp_path / "tilted.jpg"
    Image.fromarray(data).save(path, format="JPEG", quality=95, exif=exif)
    entry = capture_one(_Known(96), path, tmp_path / "out", CaptureOptions(refine=2, relit="none"))
    x, y, z = entry["flash"]["position"]
    assert (x, y) == pytest.approx((0.3, -0.2), abs=0.08) and entry["flash"]["placed"] == "fall-off"
    assert math.hypot(x, y, z) == pytest.approx(capture_geometry(path).distance, abs=1e-5)  # kept
    assert z < capture_geometry(path).position[2]  # off the axis: lower
    on_axis = capture_one(_Known(96), path, tmp_path / "o2", CaptureOptions(refine=2, relit="none", distance=2.0))
    assert on_axis["flash"]["position"] == pytest.approx([0.0, 0.0, 2.0], abs=1e-5)
