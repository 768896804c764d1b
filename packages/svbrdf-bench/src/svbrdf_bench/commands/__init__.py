"""The ``svbrdf-bench`` subcommands, one module each; every module lists its commands in ``COMMANDS``."""

# Nothing of its own: each command module is reached through svbrdf_bench.cli.
__all__: list[str] = []
