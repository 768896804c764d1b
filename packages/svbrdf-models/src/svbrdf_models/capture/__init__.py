"""The photo tool: flash photos to material folders (``svbrdf-models predict``).

The public API is :data:`__all__` below: one photo end to end (:mod:`~svbrdf_models.capture.one`)
and the steps usable alone, each imported here from the module that defines it, its one
address beside this one. The modules:

- :mod:`~svbrdf_models.capture.batch`: many photos into one folder and its ``summary.json``, the
  ``predict`` command's work;
- :mod:`~svbrdf_models.capture.photos`: reading and judging photos;
- :mod:`~svbrdf_models.capture.tiles`: tiled prediction and its memory cost;
- :mod:`~svbrdf_models.capture.refining`: the network's maps refined against the photo;
- :mod:`~svbrdf_models.capture.relight`: the flash fit, the relit versions and relit.gif;
- :mod:`~svbrdf_models.capture.reference`: a region of known albedo (``--reference``);
- :mod:`~svbrdf_models.capture.geometry`: where the camera stood, from EXIF, the crop,
  ``--fov`` or ``--distance``, and where its flash was taken to be (the photo's highlight);
- :mod:`~svbrdf_models.capture.figures`: the error heat map and the re-rendering figure;
- :mod:`~svbrdf_models.capture.material`: the material folder, its files declared once
  (``FOLDER``), written whole, and its material.json;
- :mod:`~svbrdf_models.capture.frame`: the printed capture frame (``svbrdf-models frame``);
- :mod:`~svbrdf_models.capture.framephoto`: the frame found in a photo, the window rectified,
  the camera and the flash placed.

Needs the ``photo`` extra (``pip install svbrdf-models[photo]``).
"""

from .batch import write_summary
from .figures import HEAT_MAX, error_heatmap
from .material import to_directx
from .one import (
    ALBEDO_ENCODINGS,
    MIN_TILEABLE_PHOTO,
    NORMAL_ALIASES,
    NORMAL_CONVENTIONS,
    RELIT_FORMATS,
    CaptureOptions,
    capture_one,
)
from .photos import MAX_PIXELS, MIN_SIDE, PhotoError, load_photo, orient, square
from .relight import FLASH_FIT, flash_consistency, relight_frames
from .tiles import check_tiled_memory, tile_count, tile_predict, tiled_capture_bytes

__all__ = [
    "ALBEDO_ENCODINGS",
    "CaptureOptions",
    "FLASH_FIT",
    "HEAT_MAX",
    "MAX_PIXELS",
    "MIN_SIDE",
    "MIN_TILEABLE_PHOTO",
    "NORMAL_ALIASES",
    "NORMAL_CONVENTIONS",
    "PhotoError",
    "RELIT_FORMATS",
    "capture_one",
    "check_tiled_memory",
    "error_heatmap",
    "flash_consistency",
    "load_photo",
    "orient",
    "relight_frames",
    "square",
    "tile_count",
    "tile_predict",
    "tiled_capture_bytes",
    "to_directx",
    "write_summary",
]
