"""The procedural families declare their own drawing order and weight: adding a family is adding
one module, and the weights, the drawing order and the generator's version follow from it."""

from __future__ import annotations

import importlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import svbrdf_train
from svbrdf_models.errors import DataError
from svbrdf_train.data.procedural import (
    FAMILIES,
    FAMILY_WEIGHTS,
    GENERATOR_VERSION,
    families,
    generator_version,
)

#: What generator 3 draws its families by: their drawing order and weights.
V3_WEIGHTS = {
    "stone": 1.0,
    "tiles": 1.0,
    "cells": 1.0,
    "wood": 0.6,
    "metal": 1.2,
    "fabric": 0.5,
    "plaster": 0.6,
    "rusted": 0.7,
    "bark": 0.4,
    "rock": 0.6,
}


def test_each_family_declares_its_order_and_weight_in_its_own_module():
    for name in FAMILIES:
        module = importlib.import_module(f"svbrdf_train.data.procedural.families.{name}")
        source = Path(module.__file__).read_text()
        family = families.FAMILY_TABLE[name]
        assert re.search(rf"\border={family.order}\b", source), name
        assert re.search(rf"\bweight={re.escape(str(family.weight))}\b", source), name
    orders = [families.FAMILY_TABLE[name].order for name in FAMILIES]
    assert orders == sorted(orders) and len(set(orders)) == len(orders)
    assert FAMILY_WEIGHTS == {name: f.weight for name, f in families.FAMILY_TABLE.items()}
    # Generator 3's table, bit for bit: the same families, order and weights, the same version.
    assert list(FAMILY_WEIGHTS.items()) == list(V3_WEIGHTS.items())
    assert GENERATOR_VERSION == generator_version() == "3"


def test_the_family_modules_share_no_paragraph_of_their_docstrings():
    # How a family module looks is said once, in the package's docstring; each family's own says
    # what that family draws.
    seen: dict[str, str] = {}
    for name in FAMILIES:
        doc = importlib.import_module(f"svbrdf_train.data.procedural.families.{name}").__doc__
        for paragraph in (" ".join(p.split()) for p in doc.split("\n\n")):
            assert seen.setdefault(paragraph, name) == name, (name, seen[paragraph], paragraph)
    assert "register(Family(" in families.__doc__


def test_the_table_keeps_the_declared_order_whatever_the_registration_order():
    saved = dict(families.FAMILY_TABLE)
    stone = families.FAMILY_TABLE["stone"]
    probe = families.Family("probe", "a probe", stone.draw, stone.fields, order=15, weight=0.5)
    try:
        families.register(probe)
        assert list(families.FAMILY_TABLE)[:3] == ["stone", "probe", "tiles"]
        assert families.family_fingerprint() != families.family_fingerprint(saved)
        clash = families.Family("clash", "a clash", stone.draw, stone.fields, order=15, weight=1.0)
        with pytest.raises(DataError, match="'probe' and 'clash' both declare order 15"):
            families.register(clash)
    finally:
        families.FAMILY_TABLE.clear()
        families.FAMILY_TABLE.update(saved)
    assert tuple(families.FAMILY_TABLE) == FAMILIES


@pytest.mark.parametrize(
    ("order", "weight", "message"),
    [
        (1.5, 1.0, "order must be an integer"),
        (True, 1.0, "order must be an integer"),
        (1, 0.0, "weight must be > 0"),
        (1, -1.0, "weight must be > 0"),
        (1, math.nan, "weight must be a finite number"),
        (1, "1", "weight must be a finite number"),
    ],
)
def test_a_family_declares_a_whole_order_and_a_positive_weight(order, weight, message):
    stone = families.FAMILY_TABLE["stone"]
    with pytest.raises(DataError, match=message):
        families.Family("probe", "a probe", stone.draw, stone.fields, order=order, weight=weight)


def test_the_version_names_the_family_table():
    assert generator_version(families.family_fingerprint()) == "3"
    assert generator_version("0123abcd") == "3+0123abcd"
    renumbered = {
        n: families.Family(n, f.description, f.draw, f.fields, order=f.order * 2, weight=f.weight)
        for n, f in families.FAMILY_TABLE.items()
    }
    assert families.family_fingerprint(renumbered) == families.family_fingerprint()
    reweighted = dict(families.FAMILY_TABLE)
    bark = reweighted["bark"]
    reweighted["bark"] = families.Family("bark", "", bark.draw, bark.fields, order=bark.order, weight=0.5)
    assert families.family_fingerprint(reweighted) != families.family_fingerprint()


_NEW_FAMILY = '''"""A family dropped into the package: the stone family's maps under another name."""
from .base import Family, register
from .stone import draw, fields

register(Family("zinc", "a probe", draw, fields, order=35, weight=0.8))
'''

_PROBE = """import json
from svbrdf_train.data.procedural import FAMILIES, FAMILY_WEIGHTS, GENERATOR_VERSION, ProceduralMaterials, materials
data = ProceduralMaterials(300, 8, seed=0, mix=0.0)
m, names = materials(0, [0, 1], 16, family="zinc")
print(json.dumps({"families": FAMILIES, "weights": FAMILY_WEIGHTS, "version": GENERATOR_VERSION,
                  "drawn": sorted({data.family(i) for i in range(300)}), "names": names}))
"""


def test_a_family_module_dropped_into_the_package_is_drawn_with_no_other_edit(tmp_path):
    # A copy of the package with one more module in data/procedural/families/, and nothing else changed.
    package = Path(svbrdf_train.__file__).parent
    shutil.copytree(package, tmp_path / "svbrdf_train", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "svbrdf_train" / "data" / "procedural" / "families" / "zinc.py").write_text(_NEW_FAMILY)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True, env=env, cwd=tmp_path
    )
    got = json.loads(out.stdout)
    assert got["families"] == ["stone", "tiles", "cells", "zinc", *FAMILIES[3:]]
    assert got["weights"] == {**V3_WEIGHTS, "zinc": 0.8}
    # The new table is named in the version, with no edit to the version either.
    stone = families.FAMILY_TABLE["stone"]
    zinc = families.Family("zinc", "", stone.draw, stone.fields, order=35, weight=0.8)
    table = {f.name: f for f in sorted([*families.FAMILY_TABLE.values(), zinc], key=lambda f: f.order)}
    assert got["version"] == f"3+{families.family_fingerprint(table)}" != GENERATOR_VERSION
    assert "zinc" in got["drawn"] and set(got["drawn"]) == {*FAMILIES, "zinc"}
    assert got["names"] == ["zinc", "zinc"]
