"""Files on disk: images, map files, material files and scene files.

- :mod:`~svbrdf_render.formats.files`: reading and writing images (8- and 16-bit PNG, JPEG, EXR),
  atomic outputs, output folders;
- :mod:`~svbrdf_render.formats.mapfiles`: maps as image files and Des18 strips;
- :mod:`~svbrdf_render.formats.materialfiles`: glTF and MaterialX materials;
- :mod:`~svbrdf_render.formats.yamlio`: scene files (YAML).

The public names are importable from :mod:`svbrdf_render` itself.
"""
