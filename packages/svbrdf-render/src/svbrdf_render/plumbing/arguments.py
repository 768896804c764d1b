"""The command lines' kit: a parser whose errors are one line, option types that name their
bounds, an option given once, a positive number read from text, and the exit statuses in words.

svbrdf-render's and svbrdf-models' command lines build their argparse parsers from it, so that a
bad value reads alike in each; svbrdf-train's and svbrdf-bench's click commands print
:data:`EXIT_STATUS` too, and :func:`positive_number` reads the model download's timeout and the
benchmark's flash intensity.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["EXIT_STATUS", "OneLineParser", "Once", "float_range", "int_range", "positive_number"]

#: The exit statuses every command line uses, in words for their ``--help``.
EXIT_STATUS = (
    "Exit status: 0 done; 2 bad arguments or input, refused before any work starts; "
    "3 a file could not be written (disk full, read-only, no permission, I/O error: the "
    "message names it, and nothing half-written is left); 130 interrupted."
)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line, ``PROG: error: ...`` with exit code 2 (no
    usage block); svbrdf-models' command line uses it too."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def int_range(low: int, high: int | None = None):
    """An argparse ``type``: an integer in ``[low, high]``; the message names the bounds."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low or (high is not None and value > high):
            bounds = f"from {low} to {high}" if high is not None else f"at least {low}"
            raise argparse.ArgumentTypeError(f"expected an integer {bounds}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


class Once(argparse.Action):
    """An argparse ``action`` for an option that may be given once: a second one is a usage
    error naming the option and both values (argparse would keep the last without a word)."""

    def __call__(self, parser, namespace, values, option_string=None):
        first = getattr(namespace, self.dest, self.default)
        if first is not self.default:

            def shown(value) -> str:
                return value.describe() if hasattr(value, "describe") else str(value)

            parser.error(
                f"{option_string} given twice ({shown(first)} and {shown(values)}): give it once, the "
                "second would silently replace the first"
            )
        setattr(namespace, self.dest, values)


def float_range(low: float | None = None, high: float | None = None, *, above: bool = False):
    """An argparse ``type``: a finite number ``>= low`` (``> low`` with ``above``) and ``<= high``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        bad = not math.isfinite(value)
        if low is not None:
            bad = bad or (value <= low if above else value < low)
        if high is not None:
            bad = bad or value > high
        if bad:
            parts = []
            if low is not None:
                parts.append(f"{'>' if above else '>='} {low:g}")
            if high is not None:
                parts.append(f"<= {high:g}")
            bounds = " " + " and ".join(parts) if parts else ""
            raise argparse.ArgumentTypeError(f"expected a finite number{bounds}, got {text}")
        return value

    parse.__name__ = "number"
    return parse


def positive_number(text: str | None) -> float | None:
    """The finite number > 0 that ``text`` spells (``"15"``, ``" 2.5e1 "``), else None: for a
    caller that says in its own words what it expected (an environment variable, an option).

    Example:
        >>> positive_number("15"), positive_number("0"), positive_number("nan"), positive_number(None)
        (15.0, None, None, None)
    """
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) and value > 0 else None
