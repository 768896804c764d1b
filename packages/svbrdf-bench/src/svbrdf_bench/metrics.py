"""Per-sample accuracy figures of predicted maps, and bootstrap intervals over test images.

:func:`evaluate` gives, per sample, the RMSE (the figures of :mod:`svbrdf_render.compare`: maps on
their stored encodings in [0, 1], renderings as a display shows them under the 6 evaluation
light/view pairs), the SSIM on the same images as the literature computes it (Wang et al. 2004:
an 11-tap Gaussian window of sigma 1.5, population rather than sample covariances, data range
1; scikit-image's defaults are a 7x7 uniform window with sample covariances, which gives other
numbers), and LPIPS when its weights are at hand
(:func:`load_lpips`, never a download). :func:`bootstrap_ci` and :func:`paired_difference`
turn per-sample figures into a mean with a 95% interval, and tell whether two models differ
by more than the choice of test images: percentile bootstraps drawn by ``scipy.stats.bootstrap``
(the paired one resamples the same test images for both models). A paired difference also
carries a two-sided bootstrap p-value (:attr:`Difference.p_value`), and :func:`holm` says which
of a report's verdicts survive a Holm-Bonferroni correction for their number.

scikit-image and SciPy are imported on first use, not at import time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from svbrdf_render import MAP_NAMES, SVBRDF, evaluation_scene, stored_value
from svbrdf_render.compare import display_rendering, map_rmse, per_sample_rmse

from .errors import BenchError

__all__ = [
    "evaluate",
    "load_lpips",
    "bootstrap_ci",
    "paired_difference",
    "holm",
    "holm_adjusted",
    "bootstrap_p_value",
    "BOOTSTRAP_METHOD",
    "Difference",
    "ssim_win_size",
    "SSIM_SIGMA",
    "SSIM_NAME",
    "ALEXNET_WEIGHTS",
]

#: torchvision's file name for the ImageNet AlexNet weights, LPIPS's default backbone.
ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"

#: An LPIPS distance: two ``(B, 3, H, W)`` tensors in [0, 1] -> ``(B,)`` distances.
LpipsFn = Callable[[Tensor, Tensor], np.ndarray]


# -- per-sample figures -------------------------------------------------------------------


#: Wang et al. 2004's SSIM: Gaussian weights of this standard deviation (in pixels).
SSIM_SIGMA = 1.5
#: The window of that Gaussian as scikit-image truncates it (3.5 sigma): 11 taps, as in the paper.
SSIM_WINDOW = 2 * int(3.5 * SSIM_SIGMA + 0.5) + 1
#: How reports name the SSIM variant of :func:`evaluate`.
SSIM_NAME = "SSIM (Wang et al. 2004: Gaussian window sigma 1.5, no sample covariance, data range 1)"


def ssim_win_size(height: int, width: int) -> int:
    """The SSIM window: Wang et al.'s 11 px, or the largest odd size that fits a smaller image.

    With Gaussian weights the window size only decides the border left out of the mean (half a
    window on each side) and the smallest image accepted; the weights stay the same Gaussian.
    """
    side = min(height, width)
    if side < 3:
        raise BenchError(
            f"SSIM needs images of at least 3x3 pixels, got {height}x{width}; evaluate larger images"
        )
    return min(SSIM_WINDOW, side if side % 2 else side - 1)


def _stored(svbrdf: SVBRDF) -> dict[str, np.ndarray]:
    """The maps as files store them, in [0, 1], as float64 ``(B, C, H, W)`` arrays."""
    out = {}
    for name, t in svbrdf.maps().items():
        out[name] = stored_value(name, t).detach().to("cpu", torch.float64).numpy()
    return out


def _ssim(a: np.ndarray, b: np.ndarray, win_size: int) -> float:
    """SSIM of two ``(C, H, W)`` images in [0, 1], Wang et al. 2004's variant (see :data:`SSIM_NAME`)."""
    from skimage.metrics import structural_similarity

    wang = {"gaussian_weights": True, "sigma": SSIM_SIGMA, "use_sample_covariance": False, "data_range": 1.0}
    if a.shape[0] == 1:
        return float(structural_similarity(a[0], b[0], win_size=win_size, **wang))
    return float(structural_similarity(a, b, win_size=win_size, channel_axis=0, **wang))


def evaluate(pred: SVBRDF, target: SVBRDF, *, lpips: LpipsFn | None = None) -> dict[str, np.ndarray]:
    """Per-sample figures of ``pred`` against ``target``, each a float64 array ``(B,)``.

    Keys: ``rmse/<map>`` and ``ssim/<map>`` for each map of ``MAP_NAMES``, ``rmse/render`` and
    ``ssim/render`` (the mean SSIM over the 6 evaluation renderings of a sample; SSIM is
    :data:`SSIM_NAME`, colour images averaged over channels), and, when an
    ``lpips`` callable is given (see :func:`load_lpips`), ``lpips/<map>`` and ``lpips/render``.
    Roughness is shown to LPIPS as grey RGB.
    """
    if pred.shape != target.shape:
        raise BenchError(f"evaluate: prediction is {pred.shape}, ground truth {target.shape} (B, H, W)")
    b, h, w = target.shape
    win = ssim_win_size(h, w)
    out: dict[str, np.ndarray] = {}

    def as_array(t: Tensor) -> np.ndarray:
        return t.detach().to("cpu", torch.float64).numpy()

    for name, v in map_rmse(pred, target).items():
        out[f"rmse/{name}"] = as_array(v)
    p_maps, t_maps = _stored(pred), _stored(target)
    for name in MAP_NAMES:
        out[f"ssim/{name}"] = np.array([_ssim(p_maps[name][k], t_maps[name][k], win) for k in range(b)])

    scene = evaluation_scene(device=target.device)
    with torch.no_grad():
        p_img = display_rendering(pred, scene)  # (B, 6, 3, H, W), rendered once for RMSE and SSIM
        t_img = display_rendering(target, scene)
    out["rmse/render"] = as_array(per_sample_rmse(p_img, t_img))
    p_np, t_np = as_array(p_img), as_array(t_img)
    out["ssim/render"] = np.array(
        [np.mean([_ssim(p_np[k, i], t_np[k, i], win) for i in range(p_np.shape[1])]) for k in range(b)]
    )

    if lpips is not None:
        pm, tm = pred.maps(), target.maps()
        for name in MAP_NAMES:
            p, t = stored_value(name, pm[name].detach()), stored_value(name, tm[name].detach())
            if p.shape[1] == 1:
                p, t = p.expand(-1, 3, -1, -1), t.expand(-1, 3, -1, -1)
            out[f"lpips/{name}"] = np.asarray(lpips(p.float(), t.float()), dtype=np.float64).reshape(b)
        n = p_img.shape[1]
        d = lpips(p_img.flatten(0, 1).float(), t_img.flatten(0, 1).float())
        out["lpips/render"] = np.asarray(d, dtype=np.float64).reshape(b, n).mean(axis=1)
    return out


# -- LPIPS, only from local weights -------------------------------------------------------


def _alexnet_weights(path: str | Path | None) -> Path:
    if path is None:
        return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_WEIGHTS
    p = Path(path).expanduser()
    return p / ALEXNET_WEIGHTS if p.is_dir() else p


def load_lpips(path: str | Path | None = None) -> tuple[LpipsFn | None, str]:
    """LPIPS (AlexNet) when the ``lpips`` package and the backbone weights are here; never downloads.

    Args:
        path: torchvision's AlexNet weights file (or a folder holding ``alexnet-owt-7be5be79.pth``);
            default: torch hub's cache, ``torch.hub.get_dir()/checkpoints/alexnet-owt-7be5be79.pth``.

    Returns:
        ``(distance, message)``: ``distance`` takes two ``(B, 3, H, W)`` tensors in [0, 1] and
        returns ``(B,)`` numpy distances; or ``(None, "LPIPS skipped: <reason and remedy>")``.
    """
    weights = _alexnet_weights(path)
    remedy = f"pip install lpips, and place torchvision's AlexNet weights at {weights}"
    try:
        import lpips as lpips_pkg
    except Exception as e:  # ImportError, or lpips's own imports (torchvision) failing
        return (
            None,
            f"LPIPS skipped: the lpips package cannot be imported ({type(e).__name__}: {e}); {remedy}",
        )
    if not weights.is_file():
        return None, f"LPIPS skipped: no AlexNet weights at {weights}; {remedy}"
    try:
        # A random backbone (no download); the linear layers ship with the package.
        model = lpips_pkg.LPIPS(net="alex", pnet_rand=True, verbose=False)
        state = torch.load(weights, map_location="cpu", weights_only=True)
        slices = [(0, 2), (2, 5), (5, 8), (8, 10), (10, 12)]  # lpips's cut of alexnet.features
        backbone = {}
        for key, value in state.items():
            parts = key.split(".")
            if parts[0] != "features":
                continue
            i = int(parts[1])
            s = next(k for k, (lo, hi) in enumerate(slices, 1) if lo <= i < hi)
            backbone[f"slice{s}.{i}.{parts[2]}"] = value
        model.net.load_state_dict(backbone)
        model.eval()
    except Exception as e:
        return (
            None,
            f"LPIPS skipped: cannot load LPIPS with the weights at {weights} ({type(e).__name__}: {e})",
        )

    def distance(a: Tensor, b: Tensor) -> np.ndarray:
        m = model.to(a.device)
        with torch.no_grad():
            d = m(a.float(), b.float(), normalize=True)
        return d.reshape(a.shape[0]).to("cpu", torch.float64).numpy()

    return distance, f"LPIPS (AlexNet) from {weights}"


# -- bootstrap ----------------------------------------------------------------------------


def _samples(values, what: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size == 0:
        raise BenchError(f"{what}: no values (no test images?)")
    if not np.isfinite(v).all():
        raise BenchError(f"{what}: {int((~np.isfinite(v)).sum())} of {v.size} values are NaN or infinite")
    return v


def _check(n_boot: int, level: float, what: str) -> None:
    if n_boot < 1:
        raise BenchError(f"{what}: n_boot must be at least 1, got {n_boot}")
    if not 0 < level < 1:
        raise BenchError(f"{what}: level must be in (0, 1), got {level}")


#: The interval :func:`bootstrap_ci` and :func:`paired_difference` give: the percentile bootstrap,
#: the ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of the resampled means: the figures
#: the bench's reports gave before SciPy drew them. SciPy's default, BCa, shifts those quantiles
#: for bias and skew, estimated by a jackknife over the samples: over a folder of strips that is
#: 4 to 9 materials, too few to estimate skew. On the shipped model's per-material figures BCa
#: gave the same verdicts against ``mean``; it moved skewed bounds (unseen-dev roughness
#: [0.086, 0.256] to [0.100, 0.307]).
BOOTSTRAP_METHOD = "percentile"


def _mean_difference(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(a - b, axis=axis)


def _bootstrap(
    data: tuple[np.ndarray, ...], statistic, n_boot: int, level: float, seed: int
) -> tuple[float, float, np.ndarray | None]:
    """``(low, high, resampled)``: ``scipy.stats.bootstrap``'s percentile interval of ``statistic``
    over ``data`` (one array, or two resampled together: the same indices for both), drawn from
    ``numpy.random.default_rng(seed)``: ``n_boot`` rows of indices, each ``len`` draws in
    ``[0, len)``, and the ``n_boot`` resampled statistics. One value cannot be resampled: its
    interval is that value, and ``resampled`` is None."""
    if data[0].size == 1:
        value = float(statistic(*data, axis=-1))
        return value, value, None
    from scipy.stats import bootstrap

    result = bootstrap(
        data,
        statistic,
        n_resamples=n_boot,
        confidence_level=level,
        method=BOOTSTRAP_METHOD,
        paired=len(data) > 1,
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    low, high = result.confidence_interval
    return float(low), float(high), np.asarray(result.bootstrap_distribution).reshape(-1)


def bootstrap_ci(
    values, *, n_boot: int = 2000, level: float = 0.95, seed: int = 0
) -> tuple[float, float, float]:
    """``(mean, low, high)``: the mean over samples and its percentile-bootstrap interval
    (``scipy.stats.bootstrap``, see :data:`BOOTSTRAP_METHOD`).

    Deterministic for a given ``seed``; one sample gives ``(v, v, v)``.
    """
    _check(n_boot, level, "bootstrap_ci")
    v = _samples(values, "bootstrap_ci")
    low, high, _ = _bootstrap((v,), np.mean, n_boot, level, seed)
    return float(v.mean()), low, high


@dataclass(frozen=True)
class Difference:
    """``mean(a - b)`` over the same test images, with its bootstrap interval."""

    mean: float
    low: float
    high: float
    #: The interval contains 0: the two cannot be told apart on these test images.
    within_noise: bool
    #: Two-sided bootstrap p-value of "no difference" (:func:`bootstrap_p_value`); NaN: not computed.
    p_value: float = math.nan

    def verdict(self, better: str = "beats") -> str:
        """``"within noise"`` when the interval contains 0, else ``better`` (below 0) or ``"worse"``."""
        return "within noise" if self.within_noise else (better if self.high < 0 else "worse")

    def percent_of(self, base: float, better: str = "beats") -> str:
        """The difference and its interval in % of ``base`` (the mean of ``b``), with the verdict,
        as tables print it: ``-12% [-20, -4] beats``."""
        mean, low, high = (100 * v / base for v in (self.mean, self.low, self.high))
        return f"{mean:+.0f}% [{low:+.0f}, {high:+.0f}] {self.verdict(better)}"


def paired_difference(a, b, *, n_boot: int = 2000, level: float = 0.95, seed: int = 0) -> Difference:
    """Bootstrap of ``mean(a - b)``, resampling test images: a paired ``scipy.stats.bootstrap``
    (the same images drawn for ``a`` and ``b``), percentile interval."""
    _check(n_boot, level, "paired_difference")
    va, vb = _samples(a, "paired_difference"), _samples(b, "paired_difference")
    if va.shape != vb.shape:
        raise BenchError(
            f"paired_difference: {va.size} values against {vb.size}; expected one per test image for both"
        )
    low, high, resampled = _bootstrap((va, vb), _mean_difference, n_boot, level, seed)
    p = bootstrap_p_value(resampled)
    return Difference(float((va - vb).mean()), low, high, bool(low <= 0 <= high), p)


def bootstrap_p_value(resampled: np.ndarray | None) -> float:
    """Two-sided p-value of "no difference" from the resampled mean differences of a paired
    bootstrap: twice the share of resamples on the far side of zero from the bulk,
    ``2 * min(share(d* <= 0), share(d* >= 0))``, at most 1.

    The same resamples as the percentile interval, so at level 95% an interval that excludes 0
    goes with ``p < 0.05`` (up to the interval's interpolation between resamples). ``p = 0``: no
    resample on the other side, i.e. ``p < 1 / n_boot``. Identical figures (every ``d* = 0``)
    give 1; a single test image cannot be resampled (None) and gives 1: no evidence either way.
    On a handful of materials the bootstrap has few distinct resamples, and a difference of one
    sign on every material gives ``p = 0`` where an exact sign test could not go below
    ``2 ** (1 - n)`` (0.125 on 4 materials): the report says so.
    """
    if resampled is None or resampled.size == 0:
        return 1.0
    below, above = float(np.mean(resampled <= 0)), float(np.mean(resampled >= 0))
    return min(1.0, 2.0 * min(below, above))


def holm_adjusted(p_values: Sequence[float]) -> list[float]:
    """Holm-adjusted p-values, in the order given: sorted ascending, the i-th smallest (from 0)
    becomes ``max over j <= i of min(1, (m - j) * p_(j))`` for ``m`` p-values.

    >>> [round(p, 3) for p in holm_adjusted([0.01, 0.04, 0.03, 0.005])]
    [0.03, 0.06, 0.06, 0.02]
    """
    p = [float(x) for x in p_values]
    bad = [x for x in p if not 0.0 <= x <= 1.0]  # NaN fails too
    if bad:
        raise BenchError(f"holm: p-values must lie in [0, 1], got {bad[0]}")
    m, out, running = len(p), [0.0] * len(p), 0.0
    for rank, i in enumerate(sorted(range(m), key=lambda k: p[k])):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


def holm(p_values: Sequence[float], alpha: float = 0.05) -> list[bool]:
    """Which hypotheses Holm's step-down procedure rejects at family-wise level ``alpha``, in the
    order given: sort p ascending and reject while ``p_(i) <= alpha / (m - i)`` (i from 0); the
    first one kept keeps every larger one.

    >>> holm([0.01, 0.04, 0.03, 0.005], alpha=0.05)
    [True, False, False, True]
    """
    if not 0 < alpha < 1:
        raise BenchError(f"holm: alpha must be in (0, 1), got {alpha}")
    return [q <= alpha for q in holm_adjusted(p_values)]
