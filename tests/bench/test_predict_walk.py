"""benchmarks/predict_walk.py's counting (issue 48's walk of one ``predict``): files, distinct
returns into a file already left, distinct hops; and ``--merge``, the figures as if two
modules were one, before merging them."""

from __future__ import annotations

import argparse

import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def walk():
    return load_benchmark("predict_walk")


def test_returns_count_each_way_back_once_and_hops_each_pair_once(walk):
    steps = ["a.py", "b.py", "a.py", "b.py", "a.py", "c.py", "b.py"]
    # returns: b->a (twice, counted once), a->b (the second time), c->b; hops: a->b, b->a, a->c, c->b
    assert walk.figures(steps) == {"files": 3, "returns": 3, "hops": 4}


def test_a_merge_relabels_the_walk_and_collapses_the_steps_it_joins(walk):
    steps = ["cli.py", "maps.py", "geometry.py", "maps.py", "render.py", "geometry.py", "maps.py"]
    one = walk.merged(steps, {"geometry.py": "maps.py"})
    assert one == ["cli.py", "maps.py", "render.py", "maps.py"]
    assert walk.figures(one) == {"files": 3, "returns": 1, "hops": 3}
    assert walk.figures(steps)["returns"] > walk.figures(one)["returns"]
    assert walk.merged(steps, {}) == steps


@pytest.mark.parametrize("text", ["a.py", "a.py=", "a=b.py", "=b.py"])
def test_a_merge_names_two_module_paths(walk, text):
    with pytest.raises(argparse.ArgumentTypeError, match="FILE=INTO"):
        walk._move(text)
