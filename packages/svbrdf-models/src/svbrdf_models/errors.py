"""Errors of the model registry, model files and the photo tool. All derive from svbrdf_render's
SVBRDFError (a ValueError), so command lines print them as one line with exit code 2."""

from __future__ import annotations

from svbrdf_render import SVBRDFError

__all__ = [
    "RegistryError",
    "UnknownNameError",
    "DuplicateNameError",
    "PluginLoadError",
    "ConfigError",
    "ModelFileError",
    "DataError",
]


class RegistryError(SVBRDFError):
    """Something about registered generators, attention modules or discriminators."""


class UnknownNameError(RegistryError, LookupError):
    """No entry point of that kind carries that name."""


class DuplicateNameError(RegistryError):
    """Two installed distributions register the same name in the same group."""


class PluginLoadError(RegistryError):
    """An entry point is declared but importing what it names failed, or it names no ModelSpec."""


class ConfigError(RegistryError):
    """A config dict names an unknown field or gives a value of the wrong type."""


class ModelFileError(RegistryError):
    """A trained model file cannot be found, fetched, read or rebuilt into its generator."""


class DataError(SVBRDFError):
    """Bad input data: a folder, file or argument that cannot be used. Say what, which, and what to do.

    The photo tool's errors (:class:`svbrdf_models.capture.one.PhotoError`) are DataErrors;
    svbrdf-train raises the same class for its data sets (``svbrdf_train.errors.DataError`` is
    this class)."""
