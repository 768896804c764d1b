"""Errors of svbrdf-bench; all are SVBRDFError, so the command line prints one line, exit code 2."""

from __future__ import annotations

from svbrdf_render import SVBRDFError

__all__ = ["BenchError"]


class BenchError(SVBRDFError):
    """A benchmark that cannot run: unknown model, missing or empty test data, unknown run."""
