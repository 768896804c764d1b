"""Placeholder: filled in by the data work (issue 4)."""

COMMANDS: list = []
