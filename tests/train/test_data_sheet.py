"""Contact sheets: the picture's layout and content, and the `svbrdf-train data sheet` command."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from svbrdf_models.errors import DataError
from svbrdf_render.formats.mapfiles import linear_to_srgb
from svbrdf_train.cli import main
from svbrdf_train.data.procedural import ProceduralMaterials
from svbrdf_train.data.sheet import contact_sheet


def _run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def _find(sheet: torch.Tensor, tile: torch.Tensor) -> bool:
    """Whether ``tile`` (3, h, w), quantised to 8 bits, appears in ``sheet`` at some offset."""
    q = (tile * 255).round() / 255
    _, h, w = q.shape
    for top in range(sheet.shape[1] - h + 1):
        for left in range(sheet.shape[2] - w + 1):
            if torch.equal(sheet[:, top : top + h, left : left + w], q):
                return True
    return False


def test_contact_sheet_shows_photo_and_maps_display_encoded():
    batch = ProceduralMaterials(2, 16, seed=0).batch([0, 1])
    sheet = contact_sheet(batch, ["a", "b"], gap=2)
    assert sheet.dim() == 3 and sheet.shape[0] == 3
    assert sheet.shape[1] >= 2 * 16 and sheet.shape[2] >= 5 * 16
    assert sheet.min() >= 0 and sheet.max() <= 1
    maps = batch["maps"][1]
    assert _find(sheet, linear_to_srgb(batch["input"][1]))
    assert _find(sheet, ((maps[0:3] + 1) / 2).clamp(0, 1))
    assert _find(sheet, linear_to_srgb(maps[3:6]))
    assert _find(sheet, maps[6:7].expand(3, -1, -1))


def test_contact_sheet_needs_ground_truth_and_one_label_per_row():
    batch = ProceduralMaterials(2, 16, seed=0).batch([0, 1])
    with pytest.raises(DataError, match="labels"):
        contact_sheet(batch, ["only one"])
    with pytest.raises(DataError, match="'maps'"):
        contact_sheet({"input": batch["input"]})


def test_sheet_command_writes_the_sheet_png(tmp_path, capsys):
    out = tmp_path / "sheet.png"
    code, stdout, _ = _run(
        capsys, "data", "sheet", "-n", "2", "--resolution", "24", "--seed", "3", "-o", str(out)
    )
    assert code == 0 and "wrote" in stdout
    with Image.open(out) as im:
        png = np.asarray(im.convert("RGB"))
    data = ProceduralMaterials(2, 24, seed=3)
    expected = contact_sheet(data.batch([0, 1]), [f"#{i}\n{data.family(i)}" for i in range(2)])
    assert png.shape == (expected.shape[1], expected.shape[2], 3)
    assert png.shape[0] > 2 * 24 and png.shape[1] > 5 * 24
    assert np.array_equal(png, (expected.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))
    assert not list(tmp_path.glob(".*tmp"))  # the temporary file was renamed away


def test_sheet_command_with_families(tmp_path, capsys):
    out = tmp_path / "tw.png"
    code, _, _ = _run(
        capsys,
        "data",
        "sheet",
        "-n",
        "1",
        "--resolution",
        "16",
        "--family",
        "wood",
        "--family",
        "tiles",
        "--mix",
        "0",
        "-o",
        str(out),
    )
    assert code == 0 and out.is_file()


def test_unknown_family_exits_2_naming_the_families(tmp_path, capsys):
    out = tmp_path / "x.png"
    code, _, err = _run(capsys, "data", "sheet", "--family", "rubber", "-o", str(out))
    assert code == 2
    assert "rubber" in err and "stone, tiles, cells, wood, metal, fabric" in err
    assert "Traceback" not in err and not out.exists()


def test_sheet_help_teaches(capsys):
    code, stdout, _ = _run(capsys, "data", "sheet", "--help")
    assert code == 0
    assert "Examples:" in stdout and "--family" in stdout and "sRGB" in stdout
