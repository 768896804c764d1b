"""A run's data as MLflow dataset inputs: described (source, digest, schema), never stored.

A benchmark's test set (:func:`test_dataset`), a fit's training and validation data
(:func:`fit_datasets`), logged as the run's inputs (:func:`log_datasets`, the UI's "Datasets").
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["CONTENT_DIGEST_LIMIT", "files_digest", "test_dataset", "fit_datasets", "log_datasets"]

#: A dataset's files are hashed byte by byte up to this total size; above it, by names and sizes.
CONTENT_DIGEST_LIMIT = 1 << 30


def _files(path: Path) -> list[Path]:
    """The regular files of a data set at ``path`` (itself, or those under it), sorted."""
    if path.is_file():
        return [path]
    return sorted(p for p in path.rglob("*") if p.is_file())


def files_digest(paths: Sequence[str | Path], *, content: bool = True) -> str:
    """A 16-hex-digit fingerprint of the files of ``paths`` (files or folders, walked): SHA-256 of
    each file's name (relative to its folder) and bytes, in order; of names and sizes only when
    ``content`` is False or the files are over :data:`CONTENT_DIGEST_LIMIT` bytes in all."""
    import hashlib

    entries = []
    for root in map(Path, paths):
        for f in _files(root):
            name = f.name if f == root else f.relative_to(root).as_posix()
            entries.append((name, f, f.stat().st_size))
    content = content and sum(size for _, _, size in entries) <= CONTENT_DIGEST_LIMIT
    h = hashlib.sha256(b"content" if content else b"names-sizes")
    for name, f, size in entries:
        h.update(f"{name}\0{size}\0".encode())
        if content:
            with open(f, "rb") as stream:
                for block in iter(lambda: stream.read(1 << 20), b""):
                    h.update(block)
    return h.hexdigest()[:16]


def _definition_digest(definition: Mapping[str, Any]) -> str:
    """A 16-hex-digit fingerprint of what makes a generated data set."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(definition, sort_keys=True).encode()).hexdigest()[:16]


def _schema(resolution: int):
    """The samples' schema: a photo ``input`` (3 channels) and its ``maps`` (10 channels), float32,
    ``resolution`` pixels square."""
    import numpy as np
    from mlflow.types import Schema, TensorSpec

    r = int(resolution)
    return Schema([
        TensorSpec(np.dtype("float32"), (-1, 3, r, r), "input"),
        TensorSpec(np.dtype("float32"), (-1, 10, r, r), "maps"),
    ])  # fmt: skip


def _files_dataset(name: str, paths: Sequence[str | Path], resolution: int, *, content: bool):
    """A dataset of files: MLflow's local source (the first path), the digest of its files."""
    import json

    from mlflow.data.dataset_source_registry import get_dataset_source_from_json
    from mlflow.data.meta_dataset import MetaDataset

    paths = [Path(p).resolve() for p in paths]
    source = get_dataset_source_from_json(json.dumps({"uri": str(paths[0])}), source_type="local")
    digest = files_digest(paths, content=content)
    return MetaDataset(source, name=name, digest=digest, schema=_schema(resolution))


def _procedural_dataset(name: str, resolution: int, **definition: Any):
    """A generated dataset: MLflow's code source, tagged with what makes it; its digest covers that
    and the generator's version (there are no files to hash)."""
    from mlflow.data.code_dataset_source import CodeDatasetSource
    from mlflow.data.meta_dataset import MetaDataset

    tags = {
        "generator": "svbrdf_train.data.ProceduralMaterials",
        "svbrdf-train": importlib.metadata.version("svbrdf-train"),
        "resolution": int(resolution),
        **definition,
    }
    tags = {k: str(v) for k, v in tags.items()}
    digest = _definition_digest(tags)
    return MetaDataset(CodeDatasetSource(tags), name=name, digest=digest, schema=_schema(resolution))


def test_dataset(path: str | Path | None, resolution: int, *, count: int, seed: int, name: str | None = None):
    """The dataset a benchmark tests on, as MLflow records it (a meta dataset: no pixels).

    ``path`` (a Des18 folder or shards): named after it, MLflow's local source, the digest of its
    files' bytes (:func:`files_digest`). None: the procedural test set of ``count`` materials from
    ``seed`` at ``resolution``, a code source tagged with those, its digest theirs and the
    generator's version. The schema gives the tensors the models see: ``input`` and ``maps``.
    """
    if path is not None:
        return _files_dataset(name or Path(path).resolve().name, [path], resolution, content=True)
    return _procedural_dataset(
        name or f"procedural-test-seed{seed}", resolution, count=count, seed=seed, photos="des18"
    )


def fit_datasets(recipe) -> list[tuple[Any, str]]:
    """The data a fit of ``recipe`` trains and validates on, as ``(dataset, context)`` pairs
    (contexts ``training`` and ``validation``): procedural data by what makes it (seed, samples,
    capture); files by the names and sizes of their files (reading gigabytes of shards for a
    fingerprint is not cheap); each entry of a mix; the real validation set (``data.real_validation``)
    by its files' bytes."""
    d, r = recipe.data, recipe.train.resolution
    entries = list(d.mix) if d.source == "mix" and d.mix else [{"source": d.source, "path": d.path}]
    out: list[tuple[Any, str]] = []
    for i, entry in enumerate(entries):
        source = entry.get("source", "procedural")
        suffix = f"-{i}" if len(entries) > 1 else ""
        if source == "procedural":
            count = entry.get("count", d.count)
            validation = entry.get("validation", d.validation)
            for seed, n, context in ((d.seed, count, "training"), (d.seed + 1, validation, "validation")):
                if n:  # validation uses the next seed (DataSection.seed)
                    dataset = _procedural_dataset(f"procedural-seed{seed}{suffix}", r, count=n, seed=seed,
                                                  photos=d.capture)  # fmt: skip
                    out.append((dataset, context))
            continue
        path = entry.get("path") or d.path
        paths = [path] if isinstance(path, str) else list(path or ())
        if not paths or not all(Path(p).exists() for p in paths):
            continue  # the fit itself says what is missing
        name = Path(paths[0]).resolve().name + suffix
        out.append((_files_dataset(name, paths, r, content=False), "training"))
    if d.real_validation and Path(d.real_validation).exists():
        real = Path(d.real_validation)
        out.append((_files_dataset(real.resolve().name, [real], r, content=True), "validation"))
    return out


def log_datasets(client, run_id: str, datasets: Sequence[tuple[Any, str]]) -> None:
    """``(dataset, context)`` pairs as dataset inputs of run ``run_id`` (the UI's "Datasets")."""
    from mlflow.entities import DatasetInput, InputTag
    from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

    inputs = [
        DatasetInput(dataset._to_mlflow_entity(), [InputTag(MLFLOW_DATASET_CONTEXT, context)])
        for dataset, context in datasets
    ]
    if inputs:
        client.log_inputs(run_id, datasets=inputs)
