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
import sys

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.2.0"

#: Module (relative to this package) -> the public names it defines, imported on first use.
_PUBLIC: dict[str, tuple[str, ...]] = {
    # recipes: the registered names, one loaded and checked, ``--set`` overrides parsed
    ".recipe": ("list_recipes", "load_recipe", "parse_overrides"),
    # a fit's checkpoint (a local file, or the one logged in its MLflow run) and its generator
    ".training.checkpoint": ("load_checkpoint", "check_run_kept", "SNAPSHOTS_DIR"),
    ".training.init": ("download_run_checkpoint",),
    # the weights a fit saves at training budgets (train.snapshot_minutes / snapshot_steps)
    ".training.hooks": ("snapshot_name",),
    ".inference": ("load_generator",),
    # the FLOPs torch.utils.flop_counter counts while a function runs (a network's cost)
    ".training.flops": ("count_flops",),
    # MLflow: the fits' tracker and client, the run's source and datasets, links to the UI
    ".tracking": (
        "MlflowTracker", "open_client", "check_store", "tracking_uri", "git_revision", "source_tags",
        "log_datasets", "test_dataset", "ui_page", "ui_hint",
    ),  # fmt: skip
    ".training.clock": ("CLOCK_TAG",),
    # data: test and photo sets, resizing, how strips group into materials
    ".data": ("PhotoFolder", "ProceduralMaterials"),
    ".data.fitdata": ("open_materials",),
    ".data.fov": ("resize_sample",),
    ".data.real.materials": ("GROUP_BY", "group_samples", "per_material"),
    # figures and image sheets (the figures' metrics are svbrdf_render.compare's, the error of
    # bad data svbrdf_models.errors': import them from there)
    ".metrics": ("preview_flash",),
    ".data.sheet": ("map_tiles",),
    # the command line a sibling tool shares: one-line errors, the common options
    ".cli": ("OneLineErrors", "add_commands", "run_main"),
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

# Modules that moved into subpackages (issues 38 and 48): the old names import the new modules with a
# DeprecationWarning until release _MOVED_UNTIL (svbrdf_render.plumbing.moved; CHANGELOG.md).
#: The release that removes the old names below (0.2.0 keeps them, with a warning).
_MOVED_UNTIL = "0.3.0"
_MOVED = {
    "svbrdf_train.trainer": "svbrdf_train.training.trainer",
    "svbrdf_train.step": "svbrdf_train.training.step",
    "svbrdf_train.losses": "svbrdf_train.training.losses",
    "svbrdf_train.paper_weights": "svbrdf_train.recipe.paper_weights",
    "svbrdf_train.schedule": "svbrdf_train.training.schedule",
    "svbrdf_train.clock": "svbrdf_train.training.clock",
    "svbrdf_train.checkpoint": "svbrdf_train.training.checkpoint",
    "svbrdf_train.resume": "svbrdf_train.training.resume",
    "svbrdf_train.init": "svbrdf_train.training.init",
    "svbrdf_train.hooks": "svbrdf_train.training.hooks",
    "svbrdf_train.distributed": "svbrdf_train.training.distributed",
    "svbrdf_train.validation": "svbrdf_train.training.validation",
    "svbrdf_train.fitlog": "svbrdf_train.training.fitlog",
    "svbrdf_train.flops": "svbrdf_train.training.flops",
    "svbrdf_train.order": "svbrdf_train.training.order",
    "svbrdf_train.progress": "svbrdf_train.training.progress",
    "svbrdf_train.fitdata": "svbrdf_train.data.fitdata",
    "svbrdf_train.export": "svbrdf_train.training.export",
    # issue 48: the training data's rooms, and the simulated photo named for what it makes
    "svbrdf_train.data.capture": "svbrdf_train.data.simulated_photo",
    "svbrdf_train.data.procedural_maps": "svbrdf_train.data.procedural.maps",
    "svbrdf_train.data.procedural_noise": "svbrdf_train.data.procedural.noise",
    "svbrdf_train.data.families": "svbrdf_train.data.procedural.families",
    "svbrdf_train.data.des18": "svbrdf_train.data.real.des18",
    "svbrdf_train.data.materials": "svbrdf_train.data.real.materials",
    "svbrdf_train.data.kinds": "svbrdf_train.data.real.kinds",
    "svbrdf_train.data.strips": "svbrdf_train.data.real.strips",
    "svbrdf_train.data.strip_bank": "svbrdf_train.data.real.strip_bank",
    "svbrdf_train.data.strip_batch": "svbrdf_train.data.real.strip_batch",
    "svbrdf_train.data.shard_format": "svbrdf_train.data.shards.format",
}


class _MovedFinder:
    """svbrdf_render.plumbing.moved's finder for the names above, imported only when one is asked for:
    importing svbrdf_train imports neither svbrdf_render nor torch."""

    @staticmethod
    def find_spec(fullname, path=None, target=None):
        if fullname not in _MOVED:
            return None
        from svbrdf_render.plumbing.moved import spec_for

        return spec_for(fullname, _MOVED, _MOVED_UNTIL)


if _MovedFinder not in sys.meta_path:
    sys.meta_path.append(_MovedFinder)
