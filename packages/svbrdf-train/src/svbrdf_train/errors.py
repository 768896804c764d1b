"""Errors of svbrdf-train. All derive from svbrdf_render's SVBRDFError (a ValueError), so the
command line turns any of them into a one-line message and exit code 2."""

from __future__ import annotations

from svbrdf_render import SVBRDFError

__all__ = ["DataError", "ShardError", "RecipeError"]


class DataError(SVBRDFError):
    """Bad input data: a folder, file or argument that cannot be used. Say what, which, and what to do."""


class ShardError(DataError):
    """An HDF5 shard that is truncated, corrupted, incomplete or inconsistent with its siblings."""


class RecipeError(SVBRDFError):
    """A recipe that cannot be used: unknown name, section or field, or a bad value; names the file."""
