"""svbrdf-bench: which model, at what cost? Benchmarks, reports and plots of the svbrdf toolkit.

Nothing here imports mlflow, scikit-image or matplotlib at import time.
"""

__version__ = "0.1.0"
