"""The ``svbrdf-bench`` subcommands, one module each; every module lists its commands in ``COMMANDS``."""
