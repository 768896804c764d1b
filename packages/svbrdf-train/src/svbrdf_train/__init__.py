"""svbrdf-train: training data, losses, recipes and the trainer of the svbrdf toolkit.

Data lives in :mod:`svbrdf_train.data`. Nothing here imports mlflow at import time.
"""

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.1.0"
