"""Real materials: data sets made from measured or scanned maps, not drawn.

- :mod:`.des18`: the Des18 data set (photo and maps in one PNG), its crops and its eight turns;
- :mod:`.strips`: material strips (maps only), photographed on the fly by
  :mod:`svbrdf_train.data.simulated_photo`; :mod:`.strip_bank` holds them decoded (and in strip
  shards), :mod:`.strip_batch` makes their samples on a training device;
- :mod:`.materials`: how samples group into materials, and folds of materials;
- :mod:`.kinds`: the kind of a material read from its name, and per-kind weights.

Its modules are imported by name (the strips bring h5py with the strip shards), and
:mod:`svbrdf_train.data` states the public names of the data sets. Nothing here imports
:mod:`svbrdf_train.data.procedural`.
"""

# Nothing of its own: the data sets' public names are svbrdf_train.data's.
__all__: list[str] = []
