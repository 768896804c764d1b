"""The photo tool: flash photos to material folders (``svbrdf-models predict``).

The public API (:data:`__all__`) is that of :mod:`~svbrdf_models.capture.one` (one photo end to
end); beneath it:

- :mod:`~svbrdf_models.capture.batch`: many photos into one folder and its ``summary.json``, the
  ``predict`` command's work;
- :mod:`~svbrdf_models.capture.photos`: reading and judging photos;
- :mod:`~svbrdf_models.capture.tiles`: tiled prediction and its memory cost;
- :mod:`~svbrdf_models.capture.refining`: the network's maps refined against the photo;
- :mod:`~svbrdf_models.capture.relight`: the flash fit and the relit versions;
- :mod:`~svbrdf_models.capture.reference`: a region of known albedo (``--reference``);
- :mod:`~svbrdf_models.capture.geometry`: where the camera stood, from EXIF, the crop,
  ``--fov`` or ``--distance``;
- :mod:`~svbrdf_models.capture.figures`: the error heat map and the re-rendering figure;
- :mod:`~svbrdf_models.capture.material`: the material folder's files;
- :mod:`~svbrdf_models.capture.frame`: the printed capture frame (``svbrdf-models frame``);
- :mod:`~svbrdf_models.capture.framephoto`: the frame found in a photo, the window rectified,
  the camera and the flash placed.

Needs the ``photo`` extra (``pip install svbrdf-models[photo]``).
"""

from .batch import write_summary
from .one import *  # noqa: F403
from .one import __all__ as _one_all

__all__ = [*_one_all, "write_summary"]
