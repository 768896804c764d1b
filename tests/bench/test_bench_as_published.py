"""Scoring a row as published papers scored (:mod:`svbrdf_bench.published`): the window cut
out of each stored tile, the model run on it at the window's size, per-image or pooled RMSE of the
stored encodings, on [0, 1] or [-1, 1]; checked against the figures computed here by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from svbrdf_bench.published import AS_PUBLISHED, PublishedScorer, score_as_published
from svbrdf_render import MAP_NAMES, SVBRDF, stored_value
from svbrdf_train import ProceduralMaterials, resize_sample

SIDE = 40


class Constant(torch.nn.Module):
    """Grey maps at whatever size the photo has; records the sizes it was run at."""

    def __init__(self):
        super().__init__()
        self.sizes: list[tuple[int, int]] = []

    def forward(self, photo):
        self.sizes.append(tuple(photo.shape[-2:]))
        return SVBRDF.constant(photo.shape[0], tuple(photo.shape[-2:]), roughness=0.3)


@pytest.fixture(scope="module")
def tiles():
    return ProceduralMaterials(5, SIDE, seed=11)


def _by_hand(tiles, window) -> dict[str, np.ndarray]:
    """Per tile and map: the RMSE of the grey maps against ``window(sample)``'s stored maps."""
    out = {m: [] for m in MAP_NAMES}
    for i in range(len(tiles)):
        maps = window(tiles[i])["maps"]
        truth = SVBRDF.unpack(maps[None].float(), validate=False).maps()
        grey = SVBRDF.constant(1, tuple(maps.shape[-2:]), roughness=0.3).maps()
        for m in MAP_NAMES:
            d = stored_value(m, grey[m]).double() - stored_value(m, truth[m]).double()
            out[m].append(float(d.pow(2).mean().sqrt()))
    return {m: np.asarray(v) for m, v in out.items()}


def _crop(size):
    def cut(sample):
        o = (sample["maps"].shape[-1] - size) // 2
        return {"maps": sample["maps"][..., o : o + size, o : o + size]}

    return cut


def test_the_centre_window_is_scored_at_its_own_size_per_image(tiles):
    model = Constant()
    figures = score_as_published(model, tiles, PublishedScorer("centre-crop", 32, "[0, 1]", "per-image"),
                                 torch.device("cpu"), batch=2)  # fmt: skip
    assert set(model.sizes) == {(32, 32)}  # run on the window, not at a training resolution
    expected = _by_hand(tiles, _crop(32))
    for m in MAP_NAMES:
        assert figures[f"{AS_PUBLISHED}rmse/{m}"] == pytest.approx(expected[m].mean(), rel=1e-5)
    assert figures[f"{AS_PUBLISHED}images"] == len(tiles)


def test_the_window_is_the_centre_not_the_corner(tiles):
    centre = _by_hand(tiles, _crop(16))
    corner = _by_hand(tiles, lambda s: {"maps": s["maps"][..., :16, :16]})
    figures = score_as_published(Constant(), tiles, PublishedScorer("centre-crop", 16, "[0, 1]", "per-image"),
                                 torch.device("cpu"))  # fmt: skip
    got = np.array([figures[f"{AS_PUBLISHED}rmse/{m}"] for m in MAP_NAMES])
    assert np.allclose(got, [centre[m].mean() for m in MAP_NAMES], rtol=1e-5)
    assert not np.allclose(got, [corner[m].mean() for m in MAP_NAMES], rtol=1e-3)


def test_resize_brings_the_whole_tile_to_the_size(tiles):
    model = Constant()
    figures = score_as_published(model, tiles, PublishedScorer("resize", 20, "[0, 1]", "per-image"),
                                 torch.device("cpu"))  # fmt: skip
    assert set(model.sizes) == {(20, 20)}
    expected = _by_hand(tiles, lambda s: resize_sample(s, 20))
    for m in MAP_NAMES:
        assert figures[f"{AS_PUBLISHED}rmse/{m}"] == pytest.approx(expected[m].mean(), rel=1e-5)


def test_pooled_is_one_root_over_all_images_and_the_range_scales(tiles):
    cpu = torch.device("cpu")
    per_image = score_as_published(Constant(), tiles, PublishedScorer("centre-crop", 32, "[0, 1]", "per-image"), cpu)
    pooled = score_as_published(Constant(), tiles, PublishedScorer("centre-crop", 32, "[0, 1]", "pooled"), cpu)
    wide = score_as_published(Constant(), tiles, PublishedScorer("centre-crop", 32, "[-1, 1]", "per-image"), cpu)
    expected = _by_hand(tiles, _crop(32))
    for m in MAP_NAMES:
        key = f"{AS_PUBLISHED}rmse/{m}"
        assert pooled[key] == pytest.approx(np.sqrt(np.mean(expected[m] ** 2)), rel=1e-5)
        assert pooled[key] >= per_image[key] - 1e-12  # a root of a mean is never below the mean of roots
        assert wide[key] == pytest.approx(2 * per_image[key], rel=1e-12)
