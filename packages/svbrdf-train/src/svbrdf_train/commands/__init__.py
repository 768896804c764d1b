"""The commands of ``svbrdf-train`` (:mod:`svbrdf_train.cli`), one module per command."""

# Nothing of its own: each command module is reached through svbrdf_train.cli.
__all__: list[str] = []
