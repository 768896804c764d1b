"""``svbrdf-models``: what generators, attention modules and discriminators are installed, what a
trained model file holds, maps from flash photos (``predict``), and a model served over HTTP
(``serve``).

The commands live in :mod:`svbrdf_models.commands`, one module each; this module builds the
parser from them and runs one, turning the project's errors into one line and an exit status."""

from __future__ import annotations

import sys

from svbrdf_render import SVBRDFError
from svbrdf_render.errors import exit_status
from svbrdf_render.plumbing import OneLineParser

from . import __version__
from ._registry import Registry, default_registry
from .commands import frame, names, predict, serve, show

__all__ = ["build_parser", "main"]

#: Each command's ``run(args, registry, out)``; ``predict`` reads the registry only when the
#: model's generator is built.
COMMANDS = {
    "list": names.run_list,
    "describe": names.run_describe,
    "show": show.run,
    "predict": predict.run,
    "serve": serve.run,
    "frame": frame.run,
}

#: Each command's ``add(subparsers)``, in the order ``--help`` lists them.
PARSERS = {
    "list": names.add_list,
    "describe": names.add_describe,
    "show": show.add_parser,
    "predict": predict.add_parser,
    "serve": serve.add_parser,
    "frame": frame.add_parser,
}


def build_parser(command: str | None = None) -> OneLineParser:
    """The parser (usage errors are one line, exit status 2) of every command, or of ``command``
    alone: a run of one command builds only its own options (``main`` does so when the first
    argument names a command; ``--help`` and a bad name get the whole list)."""
    parser = OneLineParser(
        prog="svbrdf-models",
        description="List and describe the registered generators, attention modules and discriminators "
        "(built-ins and plugins, found through entry points), show what a model file holds, and "
        "capture maps from flash photos (predict), serve a model over HTTP (serve), and print the capture "
        "frame (frame).",
        epilog="Exit status: 0 done; 2 bad arguments (an unknown name, a bad option); 130 interrupted. "
        "predict: see svbrdf-models predict --help.",
    )
    parser.add_argument("--version", action="version", version=f"svbrdf-models {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, add in PARSERS.items():
        if command in (None, name):
            add(sub)
    return parser


def main(argv: list[str] | None = None, registry: Registry | None = None) -> int:
    given = sys.argv[1:] if argv is None else list(argv)
    command = given[0] if given and given[0] in PARSERS else None
    try:
        args = build_parser(command).parse_args(given)
    except SystemExit as e:  # a usage error (one line, exit 2) or --help (exit 0)
        return int(e.code or 0)
    try:
        if args.command not in ("predict", "serve", "frame"):
            registry = registry or default_registry()
        return COMMANDS[args.command](args, registry, sys.stdout) or 0
    except SVBRDFError as e:  # RegistryError, a model file, a photo option, a scene: one line
        print(f"svbrdf-models: error: {e}", file=sys.stderr)
        return exit_status(e)
    except OSError as e:
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"svbrdf-models: error: {where}{e.strerror or e}", file=sys.stderr)
        return exit_status(e)
    except KeyboardInterrupt:
        print("svbrdf-models: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
