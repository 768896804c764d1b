"""File formats: images, map files, material files and scene files.

- :mod:`~svbrdf_render.formats.mapfiles`: reading and writing images (8- and 16-bit PNG, JPEG,
  EXR), maps as image files and Des18 strips;
- :mod:`~svbrdf_render.formats.gltf`: glTF 2.0 material files, and the images a material file
  names (their roles, names and checks, which MaterialX takes from there);
- :mod:`~svbrdf_render.formats.materialx`: MaterialX material files, and their check;
- :mod:`~svbrdf_render.formats.yamlio`: YAML as people write it (scene files, recipes).

How a file is written whole or not at all is :mod:`svbrdf_render.plumbing`'s. The public names
are those of the four format modules (each one's ``__all__``), all importable from here; the
most used are importable from :mod:`svbrdf_render` itself too.
"""

from . import gltf, mapfiles, materialx, yamlio
from .gltf import *  # noqa: F403
from .mapfiles import *  # noqa: F403
from .materialx import *  # noqa: F403
from .yamlio import *  # noqa: F403

__all__ = [*gltf.__all__, *mapfiles.__all__, *materialx.__all__, *yamlio.__all__]
