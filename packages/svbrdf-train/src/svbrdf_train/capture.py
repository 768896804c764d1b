"""Capture: from a real flash photo to maps. The photo tool lives in svbrdf-models
(:mod:`svbrdf_models.capture`: it needs no training code); this module names the same objects
for callers of ``svbrdf_train.capture``."""

from __future__ import annotations

from svbrdf_models.capture import (
    ALBEDO_ENCODINGS,
    FLASH_FIT,
    HEAT_MAX,
    MAX_PIXELS,
    MIN_SIDE,
    NORMAL_CONVENTIONS,
    RELIT_FORMATS,
    CaptureOptions,
    PhotoError,
    capture_one,
    error_heatmap,
    flash_consistency,
    load_photo,
    orient,
    relight_frames,
    square,
    tile_count,
    tile_predict,
    to_directx,
    write_summary,
)

__all__ = [
    "ALBEDO_ENCODINGS",
    "CaptureOptions",
    "FLASH_FIT",
    "HEAT_MAX",
    "MAX_PIXELS",
    "MIN_SIDE",
    "NORMAL_CONVENTIONS",
    "PhotoError",
    "RELIT_FORMATS",
    "capture_one",
    "error_heatmap",
    "flash_consistency",
    "load_photo",
    "orient",
    "relight_frames",
    "square",
    "tile_count",
    "tile_predict",
    "to_directx",
    "write_summary",
]
