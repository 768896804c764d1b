"""Typed errors whose messages say what was expected, what was found, and what to do."""

from __future__ import annotations

__all__ = ["SVBRDFError", "MapError", "MapFileError", "SceneError"]


class SVBRDFError(ValueError):
    """Base class of every error raised on bad input by svbrdf-render."""


class MapError(SVBRDFError):
    """A map of an :class:`~svbrdf_render.SVBRDF` has the wrong shape, dtype, device or range."""


class MapFileError(SVBRDFError):
    """A map file (Des18 strip, map folder, image) cannot be read or written."""

    def __init__(self, path, problem: str, hint: str = ""):
        self.path = str(path)
        self.problem = problem
        self.hint = hint
        msg = f"{self.path}: {problem}"
        if hint:
            msg += f" ({hint})"
        super().__init__(msg)


class SceneError(SVBRDFError):
    """A scene description is malformed: unknown effect, bad parameter, bad shape."""
