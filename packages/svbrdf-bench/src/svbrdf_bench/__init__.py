"""svbrdf-bench: which model, at what cost? Benchmarks, reports and plots of the svbrdf toolkit.

Nothing here imports mlflow, scikit-image or matplotlib at import time.
"""

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.2.0"

# svbrdf-bench is a command line (svbrdf_bench.cli); its modules are imported by name.
__all__ = ["__version__"]
