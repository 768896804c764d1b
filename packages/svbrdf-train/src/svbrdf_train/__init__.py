"""svbrdf-train: training data, losses, recipes and the trainer of the svbrdf toolkit.

Data lives in :mod:`svbrdf_train.data`. Nothing here imports mlflow at import time.

The names below (``__all__``) are the package's public API for the tools built on it (the
benchmark, svbrdf-bench, imports only these): recipes, fits' checkpoints and generators, the
MLflow tracking the fits use, the data sets, the figures and image sheets, and the command-line
pieces a sibling command shares. Each is imported from its module on first use
(``svbrdf_train.load_recipe`` imports :mod:`svbrdf_train.recipe` then), so ``import svbrdf_train``
stays instant and imports neither torch nor mlflow.
"""

from __future__ import annotations

import importlib

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.1.0"

#: Module (relative to this package) -> the public names it defines, imported on first use.
_PUBLIC: dict[str, tuple[str, ...]] = {
    # recipes: the registered names, one loaded and checked, ``--set`` overrides parsed
    ".recipe": ("list_recipes", "load_recipe", "parse_overrides"),
    # a fit's checkpoint (a local file, or the one logged in its MLflow run) and its generator
    ".checkpoint": ("load_checkpoint", "check_run_kept"),
    ".init": ("download_run_checkpoint",),
    ".inference": ("load_generator",),
    # MLflow: the fits' tracker and client, the run's source and datasets, links to the UI
    ".tracking": (
        "MlflowTracker", "open_client", "check_store", "tracking_uri", "git_revision", "source_tags",
        "log_datasets", "test_dataset", "ui_page", "ui_hint",
    ),  # fmt: skip
    ".clock": ("CLOCK_TAG",),
    # data: test and photo sets, resizing, how strips group into materials
    ".data": ("PhotoFolder", "ProceduralMaterials"),
    ".fitdata": ("open_materials",),
    ".data.fov": ("resize_sample",),
    ".data.photos": ("square_photo",),
    ".data.materials": ("GROUP_BY", "group_samples", "per_material"),
    ".errors": ("DataError",),
    # figures and image sheets
    ".metrics": ("display_rendering", "map_rmse", "per_sample_rmse", "preview_flash"),
    "svbrdf_models.capture": ("flash_consistency",),
    ".data.sheet": ("image_grid", "map_tiles"),
    # the command line a sibling tool shares: one-line errors, the common options
    ".cli": ("OneLineErrors", "run_main"),
    ".commands.options": ("experiment_option",),
    ".commands.fit": ("system_metrics_option",),
}
_WHERE = {name: module for module, names in _PUBLIC.items() for name in names}

__all__ = ["__version__", *_WHERE]


def __getattr__(name: str):
    """A public name, imported from its module on first use (PEP 562)."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # the next use is a plain lookup
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})
