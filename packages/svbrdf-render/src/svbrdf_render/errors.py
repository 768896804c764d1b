"""Typed errors whose messages say what was expected, what was found, and what to do."""

from __future__ import annotations

__all__ = ["SVBRDFError", "MapError", "MapFileError", "SceneError", "OutputError", "exit_status"]


class SVBRDFError(ValueError):
    """Base class of every error raised on bad input by svbrdf-render.

    The command lines print one as a single line and exit with :attr:`exit_code`.
    """

    #: exit status of a command line that stops on this error (2: bad input, nothing started)
    exit_code = 2


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


class OutputError(SVBRDFError):
    """A file could not be written: disk full, read-only, no permission, I/O error.

    Raised by :mod:`svbrdf_render.plumbing.atomic` after removing its temporary file, so the target
    is as it was. Command lines exit with status 3 on it.
    """

    exit_code = 3


def exit_status(error: BaseException) -> int:
    """The exit status a command line gives for ``error``: its ``exit_code``, 3 for an
    ``OSError`` that refused a write (disk full, read-only...), else 2."""
    import errno

    if isinstance(error, SVBRDFError):
        return error.exit_code
    storage = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO}
    if isinstance(error, OSError) and error.errno in storage:
        return 3
    return 2
