"""The material folder is declared once (issue 48): ``svbrdf_models.capture.material.FOLDER``
says each file's name, encoding, what it holds and when it is written, and the writer, material.json,
the ``predict --help`` listing and the table of docs/capture.md all follow it.

After a change to the declaration, print the docs table again with::

    .venv/bin/python -c "from svbrdf_models.capture.batch import folder_table; print(folder_table())"
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch

from svbrdf_models.capture.batch import folder_listing, folder_table, help_text
from svbrdf_models.capture.material import FOLDER, MATERIAL_FILES, WHEN, MaterialContent, write_material, written
from svbrdf_models.capture.one import CaptureOptions
from svbrdf_render.examples import example_material

REPO = Path(__file__).resolve().parents[2]
EXR = importlib.util.find_spec("OpenEXR") is not None


def test_the_declaration_names_each_file_once_and_material_json_last():
    names = [f.name for f in FOLDER]
    assert len(names) == len(set(names)) and MATERIAL_FILES == tuple(names)
    assert names[-1] == "material.json"  # it lists the files written before it
    assert all(f.when in WHEN for f in FOLDER)
    assert all(f.encoding in ("srgb", "linear", "albedo", "") for f in FOLDER)


def test_docs_capture_shows_the_declared_table():
    """docs/capture.md's table of the folder is the declaration's, as printed (see the module)."""
    assert folder_table() in (REPO / "docs" / "capture.md").read_text()


def test_the_predict_help_lists_every_declared_file():
    text = help_text(0)
    assert folder_listing() in text
    assert all(f"  {f.name} " in text for f in FOLDER)


def _content(options: CaptureOptions, size: int = 16) -> MaterialContent:
    """What a capture hands the writer, made up: any values of the right shapes."""
    relit = torch.rand(3, 3, size, size) if options.relit == "gif" else torch.rand(3, size, 2 * size)
    record = {"name": "shot", "photo": {"file": "shot.png", "sha256": "0" * 64}, "flash": {}}
    return MaterialContent(torch.rand(3, size, size), torch.rand(3, size, 3 * size), relit, record)


OPTIONS = [
    {},
    {"relit": "png", "normal_convention": "dx", "bits": 16},
    {"relit": "none", "albedo_encoding": "linear"},
    pytest.param({"exr": True}, marks=pytest.mark.skipif(not EXR, reason="needs OpenEXR")),
]


@pytest.mark.parametrize("given", OPTIONS, ids=["defaults", "png-dx-16", "none-linear", "exr"])
def test_the_writer_writes_exactly_the_declared_files_and_material_json_lists_them(tmp_path, given):
    options = CaptureOptions(**given)
    folder = tmp_path / "shot"
    record = write_material(folder, example_material("tiles", 16), _content(options), options)
    declared = written(options)
    assert sorted(p.name for p in folder.iterdir()) == sorted(f.name for f in declared)
    assert json.loads((folder / "material.json").read_text()) == record
    maps = {f.listed.removeprefix("maps."): f.name for f in declared if f.listed.startswith("maps.")}
    assert {key: entry["file"] for key, entry in record["maps"].items()} == maps
    others = {f.listed.removeprefix("files.") for f in FOLDER if f.listed.startswith("files.")}
    assert set(record["files"]) == others
    assert {name for name in record["files"].values() if name} == {
        f.name for f in declared if f.listed.startswith("files.")
    }
