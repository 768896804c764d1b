"""Benchmark figures: RMSE, SSIM and LPIPS per sample, bootstrap intervals, paired differences."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from conftest import random_svbrdf
from svbrdf_bench.errors import BenchError
from svbrdf_bench.metrics import (
    Difference,
    bootstrap_ci,
    evaluate,
    load_lpips,
    paired_difference,
    ssim_win_size,
)
from svbrdf_render import MAP_NAMES, SVBRDF, evaluation_scene
from svbrdf_render.compare import display_rendering

KEYS = {f"{kind}/{name}" for kind in ("rmse", "ssim") for name in (*MAP_NAMES, "render")}


def _replace(m: SVBRDF, **maps) -> SVBRDF:
    return SVBRDF(**{**m.maps(), **maps})


# -- evaluate -----------------------------------------------------------------------------


def test_identical_maps_give_rmse_0_and_ssim_1_everywhere():
    m = random_svbrdf(3, 16, seed=1)
    out = evaluate(m, m)
    assert set(out) == KEYS
    for key, v in out.items():
        assert v.shape == (3,) and v.dtype == np.float64, key
        expected = 0.0 if key.startswith("rmse") else 1.0
        np.testing.assert_allclose(v, expected, atol=1e-9, err_msg=key)


def test_constant_diffuse_offset_is_its_rmse_and_touches_no_other_map():
    m = random_svbrdf(2, 16, seed=2)
    target = _replace(m, diffuse=m.diffuse * 0.8)  # in (0.04, 0.76): +0.1 stays in [0, 1]
    pred = _replace(m, diffuse=m.diffuse * 0.8 + 0.1)
    out = evaluate(pred, target)
    np.testing.assert_allclose(out["rmse/diffuse"], 0.1, atol=1e-6)
    for name in ("normal", "roughness", "specular"):
        np.testing.assert_allclose(out[f"rmse/{name}"], 0.0, atol=1e-12)
        np.testing.assert_allclose(out[f"ssim/{name}"], 1.0, atol=1e-9)
    assert (out["rmse/render"] > 0.01).all()
    assert (out["ssim/diffuse"] < 1).all() and (out["ssim/render"] < 1).all()


def test_constant_roughness_offset_is_its_rmse():
    m = random_svbrdf(2, 16, seed=3)  # roughness in (0.1, 0.9)
    out = evaluate(_replace(m, roughness=m.roughness + 0.05), m)
    np.testing.assert_allclose(out["rmse/roughness"], 0.05, atol=1e-6)
    for name in ("normal", "diffuse", "specular"):
        np.testing.assert_allclose(out[f"rmse/{name}"], 0.0, atol=1e-12)


def test_normal_change_by_hand():
    # Stored as (n + 1) / 2: (0, 0, 1) -> (0.5, 0.5, 1.0) and (0.6, 0, 0.8) -> (0.8, 0.5, 0.9); the
    # channel differences are 0.3, 0, -0.1, so the RMSE is sqrt((0.09 + 0.01) / 3).
    target = SVBRDF.constant(batch=2, size=8)
    pred = SVBRDF.constant(batch=2, size=8, normal=(0.6, 0.0, 0.8))
    out = evaluate(pred, target)
    np.testing.assert_allclose(out["rmse/normal"], math.sqrt(0.1 / 3), atol=1e-6)
    for name in ("diffuse", "roughness", "specular"):
        np.testing.assert_allclose(out[f"rmse/{name}"], 0.0, atol=1e-12)


WANG = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}


def test_ssim_is_wangs_variant_on_the_stored_maps_and_the_display_renderings():
    target = random_svbrdf(2, 16, seed=4)
    pred = random_svbrdf(2, 16, seed=5)
    out = evaluate(pred, target)
    k = 1
    p, t = ((pred.normal[k] + 1) / 2).double().numpy(), ((target.normal[k] + 1) / 2).double().numpy()
    want = structural_similarity(p, t, channel_axis=0, **WANG)
    assert out["ssim/normal"][k] == pytest.approx(want, abs=1e-9)
    # not scikit-image's default (7x7 uniform window, sample covariance), which gives another figure
    assert abs(out["ssim/normal"][k] - structural_similarity(p, t, data_range=1.0, channel_axis=0)) > 1e-3
    want = structural_similarity(
        pred.roughness[k, 0].double().numpy(), target.roughness[k, 0].double().numpy(), **WANG
    )
    assert out["ssim/roughness"][k] == pytest.approx(want, abs=1e-9)
    scene = evaluation_scene()
    pr = display_rendering(pred, scene)[k].double().numpy()
    tr = display_rendering(target, scene)[k].double().numpy()
    assert pr.shape[0] == 6
    want = np.mean([structural_similarity(pr[i], tr[i], channel_axis=0, **WANG) for i in range(6)])
    assert out["ssim/render"][k] == pytest.approx(want, abs=1e-6)


def test_ssim_matches_wang_et_al_written_out():
    """Wang et al. 2004, eq. 13 with their choices: 11-tap Gaussian weights (sigma 1.5), weighted
    (population) moments, C1 = (0.01 L)^2, C2 = (0.03 L)^2 with L = 1, the mean SSIM over the pixels
    a whole window covers."""
    from scipy.ndimage import gaussian_filter

    g = torch.Generator().manual_seed(9)
    t = torch.rand(1, 1, 24, 24, generator=g)
    p = (t + 0.1 * torch.randn(1, 1, 24, 24, generator=g)).clamp(0, 1)
    m = SVBRDF.constant(1, 24)
    out = evaluate(_replace(m, roughness=p), _replace(m, roughness=t))
    x, y = p[0, 0].double().numpy(), t[0, 0].double().numpy()

    def w(a):
        return gaussian_filter(a, sigma=1.5, truncate=3.5, mode="reflect")

    mx, my = w(x), w(y)
    vx, vy, cxy = w(x * x) - mx**2, w(y * y) - my**2, w(x * y) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    assert out["ssim/roughness"][0] == pytest.approx(s[5:-5, 5:-5].mean(), abs=1e-9)


def test_ssim_decreases_with_noise():
    m = random_svbrdf(1, 32, seed=6)
    g = torch.Generator().manual_seed(0)
    noise = torch.randn(m.diffuse.shape, generator=g)
    ssim, rmse = [], []
    for sigma in (0.0, 0.02, 0.05, 0.15):
        out = evaluate(_replace(m, diffuse=(m.diffuse + sigma * noise).clamp(0, 1)), m)
        ssim.append(out["ssim/diffuse"][0])
        rmse.append(out["rmse/diffuse"][0])
    assert ssim[0] == pytest.approx(1.0) and all(np.diff(ssim) < 0)
    assert rmse[0] == 0 and all(np.diff(rmse) > 0)


def test_tiny_images_use_a_smaller_ssim_window():
    sizes = (3, 4, 5, 6, 7, 8, 10, 11, 12, 256)
    assert [ssim_win_size(s, s) for s in sizes] == [3, 3, 5, 5, 7, 7, 9, 11, 11, 11]
    assert ssim_win_size(4, 100) == 3
    for size in (3, 4, 6):
        m = random_svbrdf(2, size, seed=7)
        out = evaluate(m, m)
        np.testing.assert_allclose(out["ssim/render"], 1.0, atol=1e-9)
        assert out["ssim/diffuse"].shape == (2,)
    with pytest.raises(BenchError, match="3x3"):
        evaluate(random_svbrdf(1, 2), random_svbrdf(1, 2))


def test_evaluate_rejects_different_sizes():
    with pytest.raises(BenchError, match="ground truth"):
        evaluate(random_svbrdf(1, 8), random_svbrdf(1, 16))


def test_lpips_figures_when_a_distance_is_given():
    calls = []

    def fake_lpips(a, b):
        assert a.dim() == 4 and a.shape[1] == 3 and a.shape == b.shape
        assert 0 <= float(a.min()) and float(a.max()) <= 1
        calls.append(a.shape[0])
        return (a - b).abs().flatten(1).mean(1).numpy()

    m = random_svbrdf(2, 8, seed=8)
    out = evaluate(_replace(m, roughness=m.roughness + 0.05), m, lpips=fake_lpips)
    assert set(out) == KEYS | {f"lpips/{n}" for n in (*MAP_NAMES, "render")}
    assert calls == [2, 2, 2, 2, 12]  # the four maps, then the 6 renderings of each sample at once
    np.testing.assert_allclose(out["lpips/roughness"], 0.05, atol=1e-6)
    np.testing.assert_allclose(out["lpips/diffuse"], 0.0)
    assert out["lpips/render"].shape == (2,) and out["lpips/render"].dtype == np.float64
    assert (out["lpips/render"] > 0).all()


def test_load_lpips_skips_when_the_package_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "lpips", None)  # `import lpips` raises ImportError
    fn, reason = load_lpips()
    assert fn is None
    assert reason.startswith("LPIPS skipped:") and "pip install lpips" in reason
    assert "alexnet-owt-7be5be79.pth" in reason


def test_load_lpips_never_downloads_missing_weights(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "lpips", types.ModuleType("lpips"))
    fn, reason = load_lpips(tmp_path / "nowhere.pth")
    assert fn is None and "LPIPS" in reason and str(tmp_path / "nowhere.pth") in reason
    fn, reason = load_lpips(tmp_path)  # a folder: the weights file is looked for inside
    assert fn is None and str(tmp_path / "alexnet-owt-7be5be79.pth") in reason


# -- bootstrap ----------------------------------------------------------------------------


def test_bootstrap_of_constant_values_has_zero_width():
    mean, low, high = bootstrap_ci([0.25] * 40)
    assert mean == low == high == 0.25
    assert bootstrap_ci([3.5]) == (3.5, 3.5, 3.5)


def test_bootstrap_interval_covers_the_mean_and_shrinks_with_more_samples():
    rng = np.random.default_rng(1)
    widths = []
    for n in (20, 80, 320):
        v = rng.normal(5.0, 1.0, n)
        mean, low, high = bootstrap_ci(v)
        assert mean == pytest.approx(v.mean())
        assert low < mean < high
        assert low < 5.0 < high
        widths.append(high - low)
        # The normal-theory 95% interval is 2 * 1.96 * sd / sqrt(n).
        assert high - low == pytest.approx(2 * 1.96 * v.std(ddof=1) / math.sqrt(n), rel=0.2)
    assert widths[0] > widths[1] > widths[2]


def test_bootstrap_is_deterministic_with_the_seed():
    v = np.random.default_rng(2).normal(size=30)
    assert bootstrap_ci(v, seed=7) == bootstrap_ci(v, seed=7)
    assert bootstrap_ci(v, seed=7) != bootstrap_ci(v, seed=8)
    assert (
        bootstrap_ci(v, level=0.5)[2] - bootstrap_ci(v, level=0.5)[1]
        < bootstrap_ci(v)[2] - bootstrap_ci(v)[1]
    )


def test_bootstrap_rejects_empty_or_non_finite_values():
    with pytest.raises(BenchError, match="no values"):
        bootstrap_ci([])
    with pytest.raises(BenchError, match="NaN"):
        bootstrap_ci([1.0, float("nan")])
    with pytest.raises(BenchError, match="level"):
        bootstrap_ci([1.0, 2.0], level=1.0)


def _hand_written_bootstrap(v, *, n_boot=2000, level=0.95, seed=0):
    """The percentile bootstrap the bench drew by hand before ``scipy.stats.bootstrap`` (kept
    here as the reference): ``n_boot`` rows of indices from ``default_rng(seed)``, the mean of
    each row, and their ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles."""
    v = np.asarray(v, dtype=np.float64)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, v.size, size=(n_boot, v.size))
    means = v[idx].mean(axis=1)
    tail = (1 - level) / 2
    low, high = np.quantile(means, [tail, 1 - tail])
    return float(v.mean()), float(low), float(high)


@pytest.mark.parametrize(
    ("n", "n_boot", "level", "seed"),
    [(2, 2000, 0.95, 0), (4, 2000, 0.95, 0), (9, 2000, 0.95, 3), (21, 2000, 0.95, 0), (60, 500, 0.5, 7)],
)
def test_scipy_bootstrap_gives_the_hand_written_figures(n, n_boot, level, seed):
    """Same seed, same figures: SciPy draws the same indices from the same generator; only the
    quantile's last bits may differ."""
    v = np.random.default_rng(100 + n).gamma(2.0, 0.03, n)  # skewed, like per-material RMSEs
    mean, low, high = bootstrap_ci(v, n_boot=n_boot, level=level, seed=seed)
    ref_mean, ref_low, ref_high = _hand_written_bootstrap(v, n_boot=n_boot, level=level, seed=seed)
    assert mean == ref_mean
    assert low == pytest.approx(ref_low, rel=1e-12) and high == pytest.approx(ref_high, rel=1e-12)
    assert low < high  # not a degenerate draw


@pytest.mark.parametrize("n", [4, 9, 60])
def test_paired_difference_resamples_the_same_images_for_both(n):
    """The paired SciPy bootstrap gives the hand-written bootstrap of ``a - b``; two independent
    resamplings (unpaired) would give a far wider interval when images differ more than models."""
    rng = np.random.default_rng(200 + n)
    base = rng.uniform(0.05, 0.3, n)
    a, b = base + rng.normal(0.01, 0.004, n), base + rng.normal(0, 0.004, n)
    d = paired_difference(a, b, seed=5)
    ref_mean, ref_low, ref_high = _hand_written_bootstrap(a - b, seed=5)
    assert d.mean == pytest.approx(ref_mean, rel=1e-12)
    assert d.low == pytest.approx(ref_low, rel=1e-12) and d.high == pytest.approx(ref_high, rel=1e-12)
    unpaired_width = bootstrap_ci(a)[2] - bootstrap_ci(a)[1]
    assert d.high - d.low < unpaired_width / 3


def test_paired_difference_of_two_noisy_copies_is_within_noise():
    rng = np.random.default_rng(3)
    base = rng.uniform(0.05, 0.3, 60)  # per-image difficulty varies far more than the noise
    a = base + rng.normal(0, 0.005, 60)
    b = base + rng.normal(0, 0.005, 60)
    d = paired_difference(a, b)
    assert isinstance(d, Difference)
    assert d.within_noise and d.low <= 0 <= d.high
    assert d.mean == pytest.approx(float(np.mean(a - b)))


def test_paired_difference_of_a_clear_offset_is_not_within_noise():
    rng = np.random.default_rng(4)
    base = rng.uniform(0.05, 0.3, 60)
    a = base + 0.02 + rng.normal(0, 0.005, 60)
    b = base + rng.normal(0, 0.005, 60)
    d = paired_difference(a, b)
    assert not d.within_noise and 0 < d.low < 0.02 < d.high
    assert paired_difference(b, a).high < 0
    # Unpaired, the spread of the images would hide the same offset.
    lo_a, lo_b = bootstrap_ci(a)[1], bootstrap_ci(b)[2]
    assert lo_a < lo_b


def test_a_difference_reads_as_percent_of_the_baseline_with_its_verdict():
    rng = np.random.default_rng(5)
    base = rng.uniform(0.05, 0.3, 60)
    b = base + rng.normal(0, 0.005, 60)
    lower = paired_difference(base - 0.02 + rng.normal(0, 0.005, 60), b)
    text = lower.percent_of(float(np.mean(b)), "better")
    assert text.endswith("better") and text.startswith("-")
    shown = 100 * lower.mean / float(np.mean(b))
    assert text.split("%")[0] == f"{shown:+.0f}"
    assert paired_difference(b, base - 0.02).verdict() == "worse"
    noisy = paired_difference(base + rng.normal(0, 0.005, 60), b)
    assert noisy.verdict() == "within noise" and noisy.percent_of(1.0).endswith("within noise")


def test_paired_difference_needs_one_value_per_image_for_both():
    with pytest.raises(BenchError, match="3 values against 2"):
        paired_difference([1, 2, 3], [1, 2])
    with pytest.raises(BenchError, match="no values"):
        paired_difference([], [])
