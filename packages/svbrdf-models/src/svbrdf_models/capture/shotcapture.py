"""Several shots of one material captured (:func:`capture_shots`), once
:func:`~svbrdf_models.capture.shots.prepare_shots` found, posed and rectified them: the network
run once on the most frontal shot, each shot's exposure, one refinement over all of them, the
check that every shot shows the one material (:func:`check_residuals`), rerender.png
(:func:`figure`) and material.json's fields (:func:`record`, its ``shots`` keyed as a
calibrated set's, so that the viewer's keys 1-9 put the light where each shot's flash was)."""

from __future__ import annotations

import math
import statistics
import time

import torch
from torch import Tensor

from ..errors import DataError
from .multiview import Judged, finite, judge, refine_network, relit_preview, views_figure
from .shots import (ODD_FLOOR, ODD_RATIO, ODD_REFINED, Exposure, ShotSet, exposures, fitted_masks,
                    prior_relief, refine_settings, shot_scene)

__all__ = ["capture_shots", "check_residuals", "figure", "record"]


def capture_shots(predictor, shots: ShotSet, options, *, progress=None) -> dict:
    """Steps 4-6 of :mod:`~svbrdf_models.capture.shots` for the shots
    :func:`~svbrdf_models.capture.shots.prepare_shots` gave: the network run once on
    the most frontal shot, one refinement over all, each shot judged; the material folder
    written (``shots.folder``) unless the shots disagree. material.json's content."""
    from svbrdf_render import refine_start

    from .material import MaterialContent, write_material
    from .refining import as_dielectric, without_checkerboard

    began = time.monotonic()  # --refine-seconds covers the network, the refinement and the files
    f = shots.frontal
    windows = torch.stack([s.window for s in shots.shots])
    masks = torch.stack([s.mask for s in shots.shots])
    network = predictor.predict(windows[f]).detach().to("cpu", torch.float32)
    network = as_dielectric(network) if options.metal == "none" else network  # no metal: F0 0.04
    start = refine_start(without_checkerboard(network), (shots.size, shots.size))
    exposure = exposures(shots, start)
    scenes = [shot_scene(s, exposure.intensity[i], exposure.color[i]) for i, s in enumerate(shots.shots)]
    device = getattr(predictor, "device", torch.device("cpu"))
    settings = refine_settings(len(shots.shots))
    fitted = fitted_masks(windows, masks)  # the clipped pixels in, as lower bounds
    result = refine_network(network, windows, scenes, options, progress, device, masks=fitted,
                            gains=exposure.gains, anchor=exposure.anchor, began=began, settings=settings,
                            prior_relief=prior_relief(len(shots.shots)))  # fmt: skip
    gained = [shot_scene(s, exposure.intensity[i] * float(result.gains[i]), exposure.color[i])
              for i, s in enumerate(shots.shots)]  # fmt: skip
    refined = result.svbrdf.to("cpu")
    judged = judge(windows, gained, network, refined)
    residual = _log_residuals(judged.refined, windows, masks)
    if options.refine:
        check_residuals(shots, residual, _log_residuals(judged.network, windows, masks))
    content = record(predictor, shots, options, exposure, result, residual, judged)
    relit = relit_preview(network, refined, options)
    write_material(shots.folder, refined, MaterialContent(windows[f], figure(shots, windows, judged), relit,
                                                          content), options)  # fmt: skip
    return content


def _log_residuals(renderings: Tensor, windows: Tensor, masks: Tensor) -> Tensor:
    """``(K,)`` each shot's residual: the refinement's data term for it alone, the masked mean of
    ``|log(R + eps) - log(P + eps)|`` (a ratio, so a bright and a dark shot compare); NaN where
    the mask sees nothing."""
    from svbrdf_render import log_radiance
    from svbrdf_render.refinement.refine import RefineSettings

    eps = RefineSettings().eps  # 0.01
    error = (log_radiance(renderings, eps) - log_radiance(windows, eps)).abs().mean(1, keepdim=True)
    seen = masks.flatten(1).sum(1)
    value = (error * masks).flatten(1).sum(1) / seen.clamp_min(1e-12)
    return torch.where(seen > 0, value, torch.full_like(value, float("nan")))


def check_residuals(shots: ShotSet, residual: Tensor, network: Tensor) -> None:
    """Refuse (one line naming it) the shot the material of the others does not explain: its
    residual under the network's maps (``network``) more than
    :data:`~svbrdf_models.capture.shots.ODD_RATIO` times the others' median and above
    :data:`~svbrdf_models.capture.shots.ODD_FLOOR`, and under the refined maps (``residual``)
    more than :data:`~svbrdf_models.capture.shots.ODD_REFINED` times theirs: a shot of another
    material."""
    refined = [float(r) for r in residual]
    start = [float(r) for r in network]
    if len(refined) < 2:
        return
    worst, ratio = None, 0.0
    for i in range(len(refined)):
        net, ref = _stands_out(start, i), _stands_out(refined, i)
        if net is None or ref is None or start[i] <= ODD_FLOOR:
            continue
        if net[0] > ODD_RATIO and ref[0] > ODD_REFINED and net[0] > ratio:
            worst, ratio, others = i, net[0], net[1]
    if worst is not None:
        name = shots.shots[worst].path
        raise DataError(
            f"shots of different materials? {name} is not explained by the material of the other shots: the "
            f"network's maps of the most frontal shot leave it a residual of {start[worst]:.2f} (mean |log| "
            f"of rendering over photo), {ratio:.1f} times the others' median ({others:.2f}), and refining "
            f"all {len(refined)} together still {refined[worst]:.2f}; leave it out, or shoot one material"
        )


def _stands_out(values: list[float], i: int) -> tuple[float, float] | None:
    """(``values[i]`` over the median of the others, that median); None where not finite."""
    rest = [v for j, v in enumerate(values) if j != i and math.isfinite(v)]
    if not rest or not math.isfinite(values[i]):
        return None
    median = statistics.median(rest)
    return values[i] / max(median, 1e-12), median


def figure(shots: ShotSet, windows: Tensor, judged: Judged) -> Tensor:
    """rerender.png: a row per shot (its window, the network's and the refined re-rendering
    under its own camera and flash, the refined error)."""
    f = shots.frontal
    labels = [f"{s.path.name}{' (network)' if i == f else ''}" for i, s in enumerate(shots.shots)]
    return views_figure(windows, judged, labels)


def _vector(t) -> list[float | None]:
    return [finite(v) for v in t.tolist()]


def _shots(shots: ShotSet, exposure: Exposure, result, residual: Tensor, judged: Judged) -> list[dict]:
    """material.json's ``shots``: each shot used, then each one skipped."""
    out = []
    for i, s in enumerate(shots.shots):
        out.append({
            "file": s.path.name, "camera": _vector(s.camera), "light": _vector(s.flash),
            "flash_offset_cm": list(shots.flash_offset_cm), "focal_px": finite(s.focal_px),
            "focal_source": s.focal_source, "angle_deg": finite(s.angle),
            "intensity": finite(exposure.intensity[i]), "color": _vector(exposure.color[i]),
            "exposure": exposure.source[i], "gain": finite(result.gains[i]),
            "used": True, "held_out": False, "network_view": i == shots.frontal,
            "rmse_network": finite(judged.rmse_network[i]), "rmse": finite(judged.rmse[i]),
            "residual": finite(residual[i]), "masked_rmse": finite(result.residuals[i]),
            "window_px": finite(s.window_px), "markers": s.markers, "marker_rms_px": finite(s.marker_rms_px),
            "strip": shots.readings[i].record(),
        })  # fmt: skip
    for path, why in shots.skipped:
        out.append({"file": path.name, "used": False, "held_out": False, "skipped": why})
    return out


def record(predictor, shots: ShotSet, options, exposure: Exposure, result, residual: Tensor,
           judged: Judged) -> dict:  # fmt: skip
    """material.json's fields that a capture of shots knows."""
    from .material import model_record, provenance
    from .photos import photo_encoding
    from .refining import pick_backend
    from .shots import CLIPPED_FLOOR  # read when called: a study may turn it off

    from svbrdf_render import RefineSettings

    f, k, size = shots.frontal, len(shots.shots), shots.size
    mean = finite(sum(judged.rmse) / k)
    settings = refine_settings(k) or RefineSettings()
    light = shots.shots[f].flash
    return {
        "name": shots.folder.name,
        "photo": {"file": shots.shots[0].path.name, "sha256": shots.sha256(), "square": int(size),
                  "crop": None, "encoding": photo_encoding(shots.shots[0].path, options.linear),
                  "network_view": shots.shots[f].path.name},  # fmt: skip
        "model": model_record(predictor),
        "maps_size": int(size),
        "tiles": 0,
        "rerender_rmse": mean,
        "flash": {"position": _vector(light), "intensity": finite(exposure.intensity[f] * result.gains[f])},
        "refine": {"budget": options.refine, "seconds_budget": options.refine_seconds,
                   "steps": int(result.steps), "seconds": round(float(result.seconds), 3),
                   "views": k, "gains": exposure.gains, "backend": pick_backend(options.backend, size, size),
                   "prior": dict(settings.prior), "coarse": settings.coarse,
                   "clipped": "lower bound" if CLIPPED_FLOOR else "left out",
                   "prior_relief": prior_relief(k),
                   "rmse_network": finite(sum(judged.rmse_network) / k), "rmse_refined": mean},  # fmt: skip
        "frame": {
            "window_cm": shots.window_cm, "half_width_cm": shots.window_cm / 2,
            "strip_albedo": shots.strip_albedo, "flash_offset_cm": list(shots.flash_offset_cm),
            "units": "positions in half-widths of the window (cm / (window / 2)), from its centre: x right, "
            "y towards the frame's title, z towards the camera; intensity for a 1/d^2 falloff in half-widths",
            "residual": "a shot's mean |log(rendering + 0.01) - log(photo + 0.01)| over its pixels not "
            "clipped, after the one refinement of all shots (masked_rmse: the RMSE over the pixels the "
            "refinement compared, the clipped ones included)",
        },  # fmt: skip
        "shots": _shots(shots, exposure, result, residual, judged),
        "holdout": None,
        "tileable": None,
        "reference": None,
        "metal": options.metal,
        "provenance": provenance(),
    }
