"""svbrdf-models (being written)."""
