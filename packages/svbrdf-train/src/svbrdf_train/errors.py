"""Errors of svbrdf-train. All derive from svbrdf_render's SVBRDFError (a ValueError), so the
command line turns any of them into a one-line message and exit code 2."""

from __future__ import annotations

from svbrdf_models.errors import DataError
from svbrdf_render import SVBRDFError

__all__ = ["ShardError", "RecipeError", "CheckpointError", "TrainingError", "TrackingError"]


# DataError (bad input data: a folder, file or argument that cannot be used) is svbrdf-models'
# own class, so that the photo tool there and the data sets here raise one kind of error: import
# it from svbrdf_models.errors.


class ShardError(DataError):
    """An HDF5 shard that is truncated, corrupted, incomplete or inconsistent with its siblings."""


class RecipeError(SVBRDFError):
    """A recipe that cannot be used: unknown name, section or field, or a bad value; names the file."""


class CheckpointError(SVBRDFError):
    """A checkpoint that cannot be read or resumed: missing, corrupted, or from another recipe or setup."""


class TrainingError(SVBRDFError):
    """A fit that cannot start or go on: a non-finite loss, inconsistent settings, a data set too small."""


class TrackingError(SVBRDFError):
    """The MLflow store cannot be reached or refuses the run; names the store and what to do."""
