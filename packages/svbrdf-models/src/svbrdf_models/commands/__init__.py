"""The commands of ``svbrdf-models`` (:mod:`svbrdf_models.cli`), one module each: ``list`` and
``describe`` (:mod:`.names`), ``show`` (:mod:`.show`), ``predict`` (:mod:`.predict`), ``serve`` (:mod:`.serve`).

Each module has ``add_parser(sub)``, which adds its sub-command to the parser, and
``run(args, registry, out)``, which runs it (its exit status, or None for 0).
"""

# Nothing of its own: each command module is reached through svbrdf_models.cli.
__all__: list[str] = []
