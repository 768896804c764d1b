"""Reference rows: model files trained elsewhere, scored beside the models a benchmark trains.

``svbrdf-bench run --from-models FILE|SOURCE,...`` and ``--models pretrained[:NAME]`` load each
model with :func:`svbrdf_models.load_model` and evaluate it on the benchmark's test images with
the same figures as every other row. Such a model was not trained at the benchmark's budget,
so its row label says so and says what its budget was, from what its file records::

    fold0 (reference: ours, 128 px, 8.3k steps, 1.1 h CPU; not equal-budget)

Before anything trains, a reference model is refused when it runs at another resolution than
the test images, and when its provenance lists, among the real strips it trained on, strips of
the test data (unless ``--allow-trained-strips``: its label then says how many it saw).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import BenchError
from .layout import (
    BUDGET_PREFIX,
    MODEL_SHA_TAG,
    MODEL_SOURCE_TAG,
    MODEL_TAG,
    PARENT_TAG,
    REFERENCE_TAG,
    STEPS_METRIC,
    STEPS_WALL_METRIC,
)

__all__ = [
    "Reference",
    "is_pretrained",
    "split_pretrained",
    "load_references",
    "budget_words",
    "trained_files",
    "check_resolution",
    "check_trained_strips",
    "reference_child",
    "reference_figures",
]

#: MLflow takes param values up to 500 characters in its oldest stores.
_PARAM_MAX = 500


@dataclass
class Reference:
    """One model file to score as a reference row."""

    source: str
    """What the user gave (a path, ``pretrained[:NAME]``, a URL, an MLflow URI)."""
    flag: str
    """The option it came from, for messages: ``--from-models`` or ``--models``."""
    model: Any
    """The :class:`svbrdf_models.TrainedModel`."""
    name: str
    """Short name: the file's stem, the shipped model's name, the registered model's name."""
    seen: int = 0
    """Test strips the model trained on (scored anyway with ``--allow-trained-strips``)."""
    test_strips: int = 0

    @property
    def label(self) -> str:
        """The row label: not equal-budget, and what the budget was."""
        extra = f"; trained on {self.seen} of the {self.test_strips} test strips" if self.seen else ""
        return f"{self.name} (reference: {budget_words(self.model)}; not equal-budget{extra})"

    @property
    def short(self) -> str:
        """The name in plots and the comparison grid."""
        return f"{self.name} (reference)"


def is_pretrained(item: str) -> bool:
    """Whether a ``--models`` item names the model shipped with svbrdf-models."""
    return item == "pretrained" or item.startswith("pretrained:")


def split_pretrained(models: Sequence[str]) -> tuple[list[str], list[str]]:
    """``--models`` items -> (recipes to train, shipped models to score as reference rows)."""
    return [m for m in models if not is_pretrained(m)], [m for m in models if is_pretrained(m)]


def _short_name(source: str) -> str:
    if is_pretrained(source):
        from svbrdf_models.modelfile.files import PRETRAINED

        return source.partition(":")[2] or PRETRAINED
    if source.startswith("models:/"):
        return source[len("models:/") :].strip("/")
    if source.startswith("runs:/"):
        return f"run-{source[len('runs:/') :].split('/')[0][:8]}"
    if "://" in source:
        return Path(source.split("?")[0].rstrip("/").rsplit("/", 1)[-1]).stem
    return Path(source).stem or source


def load_references(items: Iterable[tuple[str, str]], device, taken: Iterable[str] = ()) -> list[Reference]:
    """Load each ``(source, flag)``; a source that cannot be loaded is a one-line BenchError.

    ``taken``: row names already used (recipes, baselines); a reference named like one of them, or
    like another reference, gets the first 8 hex digits of its SHA-256 appended.
    """
    from svbrdf_models import RegistryError, load_model

    used = set(taken)
    out = []
    for source, flag in items:
        try:
            model = load_model(source, device)
        except RegistryError as e:  # ModelFileError: missing, unreadable, not a model file
            raise BenchError(f"{flag}: {e}") from None
        name = _short_name(source)
        if name in used:
            name = f"{name}-{model.sha256[:8]}"
        used.add(name)
        out.append(Reference(source, flag, model, name))
    return out


# -- the budget a file records ------------------------------------------------------------------


def _count(n: int) -> str:
    if n >= 1_000_000:
        return f"{n / 1e6:.1f}M"
    if n >= 1000:
        return f"{n / 1000:.1f}k"
    return str(n)


def _duration(seconds: float) -> str:
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _device_words(info: dict[str, Any]) -> str:
    device = str(info.get("device") or "unknown")
    hardware = str(info.get("hardware") or "")
    world = int(info.get("world_size") or 1)
    if device.startswith("cuda"):
        gpu = hardware.split(" x ", 1)[-1].removeprefix("NVIDIA ").strip() or "GPU"
        return f"{world} x {gpu}" if world > 1 else gpu
    if device == "unknown":
        return ""
    words = device.split(":")[0].upper()
    return f"{world} x {words}" if world > 1 else words


def budget_words(model) -> str:
    """``ours, 128 px, 8.3k steps, 1.1 h CPU``: generator, resolution, steps, training time, device."""
    info = model.provenance
    steps = f"{_count(model.steps)} steps" if model.steps > 0 else "steps unknown"
    seconds = float(info.get("train_seconds") or 0.0)
    device = _device_words(info)
    time = f"{_duration(seconds)}{' ' + device if device else ''}" if seconds > 0 else "training time unknown"
    precision = ", fp16" if model.precision == "fp16" else ""
    return f"{model.name}, {model.resolution} px, {steps}, {time}{precision}"


def _real_sources(model) -> list[dict[str, Any]]:
    data = model.provenance.get("data") or {}
    return [s for s in data.get("sources") or [] if s.get("source", "procedural") != "procedural"]


def trained_files(model) -> set[str]:
    """Names of the real files (Des18 strips, shards) the model's provenance says it trained on."""
    return {str(f) for s in _real_sources(model) for f in s.get("files") or []}


# -- refusals, before anything trains -----------------------------------------------------------


def check_resolution(refs: Sequence[Reference], resolution: int, why: str) -> None:
    """Refuse a reference model that runs at another resolution than the test images."""
    for ref in refs:
        r = ref.model.resolution
        if r != resolution:
            raise BenchError(
                f"{ref.flag} {ref.source}: the model runs at {r} px, but this benchmark tests at "
                f"{resolution} px ({why}); a model is scored at the resolution it trained at: train "
                f"the recipes at {r} px (--size, or --set train.resolution={r}), or score the model "
                f"in a benchmark of its own (svbrdf-bench run {ref.flag} {ref.source} --test-data ...)"
            )


def check_trained_strips(refs: Sequence[Reference], test, allow: bool, say: Callable[[str], None]) -> None:
    """Refuse (unless ``allow``) a reference model that trained on strips of the test data
    (``test``: the :class:`~svbrdf_bench.testset.TestSet`, whose ``names`` are its files)."""
    test_names, count = test.names, len(test)
    for ref in refs:
        real = _real_sources(ref.model)
        if not real or not test_names:
            continue
        seen = sorted(trained_files(ref.model) & test_names)
        unlisted = [s.get("source", "?") for s in real if not s.get("files")]
        if unlisted:
            say(
                f"warning: {ref.flag} {ref.source}: its provenance names real training data "
                f"({', '.join(unlisted)}) without the names of its files: whether it trained on "
                "test strips cannot be checked"
            )
        if not seen:
            continue
        if not allow:
            raise BenchError(
                f"{ref.flag} {ref.source}: {len(seen)} of the {count} test strips "
                f"({test.description}) are among the real strips this model trained on (its "
                f"provenance lists them; e.g. {seen[0]!r}), so its scores there would flatter it; "
                "give --test-data a folder of strips it never saw, or --allow-trained-strips to "
                "score it anyway (its row then says how many it saw)"
            )
        ref.seen, ref.test_strips = len(seen), count
        say(
            f"warning: {ref.flag} {ref.source} trained on {len(seen)} of the {count} test "
            "strips (--allow-trained-strips); its row says so"
        )


# -- MLflow -------------------------------------------------------------------------------------


def _budget(ref: Reference) -> dict[str, str]:
    info = ref.model.provenance
    sources = []
    for s in (info.get("data") or {}).get("sources") or []:
        kind = s.get("source", "procedural")
        files = s.get("files")
        what = f"{len(files)} files" if files else f"seed {s['seed']}" if "seed" in s else ""
        weight = f" x{s['weight']:g}" if isinstance(s.get("weight"), int | float) else ""
        sources.append(f"{kind}{weight}" + (f" ({what})" if what else ""))
    return {
        "summary": budget_words(ref.model),
        "steps": str(ref.model.steps),
        "train_seconds": f"{float(info.get('train_seconds') or 0.0):.1f}",
        "wall_seconds": f"{float(info.get('wall_seconds') or 0.0):.1f}",
        "device": str(info.get("device", "unknown")),
        "hardware": str(info.get("hardware", "unknown")),
        "world_size": str(info.get("world_size", 1)),
        "recipe": str(info.get("recipe") or ref.model.recipe.get("name") or "unknown"),
        "size": str(info.get("size") or ref.model.recipe.get("size") or "unknown"),
        "samples": str(info.get("samples", "unknown")),
        "data": "; ".join(sources) or "unknown",
        "git_sha": str(info.get("git_sha", "unknown")),
        "run_id": str(info.get("run_id") or "-"),
        "trained_test_strips": str(ref.seen),
    }


def reference_child(client, experiment_id: str, parent_id: str, ref: Reference) -> str:
    """The child run of a reference model: tagged with its label, short name, SHA-256 and source;
    params ``model.*`` (the file) and ``budget.*`` (what its provenance records). Its run id."""
    from mlflow.entities import Param

    model = ref.model
    tags = {
        PARENT_TAG: parent_id,
        MODEL_TAG: ref.label,
        REFERENCE_TAG: ref.name,
        MODEL_SHA_TAG: model.sha256,
        MODEL_SOURCE_TAG: ref.source,
        "generator": model.name,
    }
    child = client.create_run(experiment_id, run_name=ref.short, tags=tags)
    values = {
        "model.source": ref.source,
        "model.sha256": model.sha256,
        "model.name": model.name,
        "model.resolution": str(model.resolution),
        "model.precision": model.precision,
        **{f"model.{k}": str(v) for k, v in model.config.items()},
        **{f"{BUDGET_PREFIX}{k}": v for k, v in _budget(ref).items()},
    }
    params = [Param(k, v[:_PARAM_MAX]) for k, v in values.items()]
    for start in range(0, len(params), 100):  # MLflow takes at most 100 params per batch
        client.log_batch(child.info.run_id, params=params[start : start + 100])
    return child.info.run_id


def reference_figures(ref: Reference) -> dict[str, float]:
    """The time table's training figures, as the file records them (its own budget)."""
    info = ref.model.provenance
    nan = float("nan")
    seconds = float(info.get("train_seconds") or 0.0)
    wall = float(info.get("wall_seconds") or 0.0)
    return {
        STEPS_METRIC: float(ref.model.steps) if ref.model.steps > 0 else nan,
        "time/train_s": seconds if seconds > 0 else nan,
        STEPS_WALL_METRIC: wall if wall > 0 else nan,
    }
