"""Recipes: named, complete training configurations, read from YAML.

A recipe file holds the sections below; a recipe may start from another (``base: ours``, or
the path of a YAML file, read from the recipe's own folder when relative) and change only
what differs, and lists ``sizes``: dotted overrides that turn the paper's configuration into
ones that finish in minutes on a CPU::

    description: the paper's model
    generator: {name: ours, config: {}}
    discriminator: {name: patchgan, config: {renderings: 9}}
    loss: {adv: 0.1, render: 0.5, svbrdf: 0.5}
    sizes:
      cpu: {generator.config.preset: small, train.resolution: 128}

Recipes are found by name through the entry-point group ``svbrdf.recipes`` (each entry
names a YAML file path; svbrdf-train registers its own that way), or given as a path. Any
field can be overridden with ``--set section.field=value`` (the value is read as YAML;
files and values alike read ``3e-4`` as a number, see :mod:`svbrdf_render.yamlio`).
Unknown sections and fields are errors naming the field and the file.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.metadata
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from svbrdf_models import ConfigError, RegistryError, build_config, param, resolve_config
from svbrdf_render.yamlio import safe_load

from .errors import RecipeError

__all__ = [
    "SIZES",
    "MAX_SEED",
    "MIN_RESOLUTION",
    "MAX_RESOLUTION",
    "RECIPE_GROUP",
    "NetworkSection",
    "LossSection",
    "OptimSection",
    "DataSection",
    "MIX_KEYS",
    "TrainSection",
    "Recipe",
    "list_recipes",
    "recipe_path",
    "load_recipe",
    "parse_overrides",
    "recipe_from_dict",
    "check_recipe",
    "recipe_differences",
    "with_overrides",
]

RECIPE_GROUP = "svbrdf.recipes"
#: Sizes every built-in recipe has: the paper's, one for a CPU in minutes, one for tests.
SIZES = ("paper", "cpu", "smoke")
#: Seeds are drawn from [0, MAX_SEED] (numpy's SeedSequence refuses negative ones).
MAX_SEED = 2**32 - 1
#: Training sizes in pixels: below, no network has a layer left; above, no GPU holds a batch.
MIN_RESOLUTION, MAX_RESOLUTION = 8, 8192


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check(ok: bool, field: str, value: Any, expected: str) -> None:
    """ValueError ``"field must be expected, got value"`` unless ``ok``."""
    if not ok:
        raise ValueError(f"{field} must be {expected}, got {value!r}")


def _finite(value: Any, field: str, *, low: float = 0.0, positive: bool = False) -> None:
    ok = _number(value) and math.isfinite(value) and (value > low if positive else value >= low)
    _check(ok, field, value, f"a finite number {'>' if positive else '>='} {low:g}")


def _int_at_least(value: Any, field: str, low: int, *, none: str | None = None) -> None:
    if value is None and none is not None:
        return
    expected = f"at least {low}" + (f" (or null: {none})" if none else "")
    _check(value is not None and value >= low, field, value, expected)


def _seed(value: int, field: str) -> None:
    _check(0 <= value <= MAX_SEED, field, value, f"in [0, {MAX_SEED}] (2**32 - 1)")


@dataclass(frozen=True)
class NetworkSection:
    name: str = param("ours", "registered name (svbrdf-models list)")
    config: dict = param({}, "config dict of that network; may hold 'preset'")


@dataclass(frozen=True)
class LossSection:
    adv: float = param(0.1, "lambda1: weight of the adversarial loss (0: no discriminator is trained)")
    render: float = param(0.5, "lambda2: weight of the log rendering loss")
    svbrdf: float = param(0.5, "lambda3: weight of the L1 map loss")
    gan: str = param(
        "bce", "adversarial objective: bce (eq. 3, non-saturating) or lsgan", choices=("bce", "lsgan")
    )
    maps: dict = param(
        {"normal": 1.0, "diffuse": 1.0, "roughness": 0.5, "specular": 0.5},
        "per-map weights of the L1 map loss",
    )
    eps: float = param(0.01, "offset of the log in the rendering loss")

    def __post_init__(self):
        for name in ("adv", "render", "svbrdf"):
            _finite(getattr(self, name), name)
        _finite(self.eps, "eps", positive=True)  # log(0) of a black rendering is -inf
        if self.adv + self.render + self.svbrdf <= 0:
            raise ValueError(
                f"at least one of adv, render and svbrdf must be positive, got {self.adv}, "
                f"{self.render} and {self.svbrdf}"
            )
        unknown = set(self.maps) - {"normal", "diffuse", "roughness", "specular"}
        if unknown:
            raise ValueError(
                f"maps: unknown map {sorted(unknown)}; maps are normal, diffuse, roughness, specular"
            )
        for name, weight in self.maps.items():
            _finite(weight, f"maps.{name}")
        if self.svbrdf > 0 and not any(w > 0 for w in self.maps.values()):
            raise ValueError(
                f"svbrdf is {self.svbrdf} but every weight of maps is 0 ({self.maps}), so the map loss "
                "is always 0; give a map a weight, or set svbrdf to 0"
            )


@dataclass(frozen=True)
class OptimSection:
    lr: float = param(2e-5, "Adam learning rate of the generator")
    d_lr: float = param(2e-5, "Adam learning rate of the discriminator")
    betas: tuple[float, float] = param((0.5, 0.999), "Adam betas")
    g_steps_per_d: int = param(5, "generator steps per discriminator step (paper: 5)")
    decay_every_samples: int | None = param(
        400_000,
        "step decay period in samples seen, whatever the data set size (paper: 2 epochs of 200k "
        "= 400000); None: no decay",
    )
    decay_every_epochs: int | None = param(
        None,
        "the period in epochs instead (set decay_every_samples to null): the same as the paper only "
        "on its 200k samples; on a small data set an epoch is a few steps",
    )
    decay: float = param(0.5, "learning-rate factor at each decay step (paper: halved)")
    warmup_samples: int = param(0, "linear warm-up of both rates over this many samples (0: none)")

    def __post_init__(self):
        _finite(self.lr, "lr", positive=True)
        _finite(self.d_lr, "d_lr", positive=True)
        for i, beta in enumerate(self.betas):
            _check(_number(beta) and 0 <= beta < 1, f"betas[{i}]", beta, "in [0, 1) (Adam's)")
        _int_at_least(self.g_steps_per_d, "g_steps_per_d", 1)
        for name in ("decay_every_samples", "decay_every_epochs"):
            _int_at_least(getattr(self, name), name, 1, none="no decay")
        if self.decay_every_samples is not None and self.decay_every_epochs is not None:
            raise ValueError(
                f"decay_every_samples={self.decay_every_samples} and decay_every_epochs="
                f"{self.decay_every_epochs} are both set; keep one (--set optim.decay_every_samples=null "
                "to count in epochs)"
            )
        _check(0 < self.decay <= 1, "decay", self.decay, "in (0, 1] (1: no decay)")
        _int_at_least(self.warmup_samples, "warmup_samples", 0)


#: The named photo captures of procedural data (``data.capture``; svbrdf_train.data.procedural's
#: ``CAPTURE_PRESETS``).
CAPTURES = ("des18", "phone")
#: Keys of one ``data.mix`` entry, and the sources an entry may name.
MIX_KEYS = ("source", "weight", "path", "count", "validation")
MIX_SOURCES = ("procedural", "shards", "des18")


@dataclass(frozen=True)
class DataSection:
    source: str = param(
        "procedural",
        "procedural (generated), shards (HDF5 files), des18 (a folder of strips) or mix (the "
        "sources of data.mix, drawn at random with their weights)",
        choices=("procedural", "shards", "des18", "mix"),
    )
    path: str | tuple[str, ...] | None = param(
        None,
        "shard file(s) or Des18 folder (--data); unused for procedural; for mix, the path of the "
        "entries that give none",
    )
    count: int = param(
        200_000,
        "procedural samples per epoch (the paper trains on ~200k); for mix, samples per epoch "
        "drawn from all sources",
    )
    seed: int = param(0, "procedural data seed; validation uses seed + 1, so the two never overlap")
    validation: int = param(64, "held-out samples for periodic validation")
    workers: int = param(0, "DataLoader worker processes (with generate: workers)")
    generate: str = param(
        "workers",
        "where training batches are made: workers (a DataLoader over data.workers CPU processes; "
        "0: in the training process) or device (in the training process, on the training device: "
        "procedural materials and their photos are computed there, the whole batch at once, and "
        "shards and Des18 strips are read on the CPU and moved). device suits a GPU, whose "
        "training outruns CPU workers generating procedural data; on a CPU both give the same "
        "bytes, on a GPU device gives the same materials with the GPU's own photo noise",
        choices=("workers", "device"),
    )
    real_validation: str | None = param(
        None,
        "a Des18 folder or .h5 shards of real materials to validate on as well, brought to the "
        "training resolution by resizing (logged as val_real/...); None: none",
    )
    mix: tuple[dict, ...] | None = param(
        None,
        "with source mix: entries {source, weight[, path, count, validation]}; each training "
        "sample comes from entry i with probability weight_i / sum(weights); validation sets "
        "are each entry's own, put together",
    )
    capture: str = param(
        "des18",
        "how procedural materials are photographed (training and validation alike): des18 (a "
        "flash at 1.8-2.75 whose irradiance follows the distance, +-0.75 EV, linear, as the "
        "Des18 inputs) or phone (the flashes fitted to real phone photos: distance 1.8-3.7 and "
        "intensity 10-21 drawn independently, white balance within 8%, half of the photos "
        "JPEG-compressed at quality 75-95)",
        choices=CAPTURES,
    )

    def __post_init__(self):
        _int_at_least(self.count, "count", 1)
        _int_at_least(self.validation, "validation", 0)
        _int_at_least(self.workers, "workers", 0)
        _seed(self.seed, "seed")
        paths = (self.path,) if isinstance(self.path, str) else self.path or ()
        if any(not p.strip() for p in paths) or self.path == ():
            raise ValueError(f"path must name files or folders (or be null), got {self.path!r}")
        if self.real_validation is not None and not self.real_validation.strip():
            raise ValueError(
                f"real_validation must name a folder or shards (or be null), got {self.real_validation!r}"
            )
        if self.source == "mix":
            if not self.mix:
                raise ValueError("source 'mix' needs data.mix: a list of {source, weight} entries")
            for i, entry in enumerate(self.mix):
                _check_mix_entry(i, entry)
        elif self.mix:
            raise ValueError(f"data.mix is set but data.source is {self.source!r}; set data.source=mix")


def _check_mix_entry(i: int, entry: Mapping[str, Any]) -> None:
    where = f"mix[{i}]"
    unknown = set(entry) - set(MIX_KEYS)
    if unknown:
        key = sorted(unknown)[0]
        raise ValueError(
            f"{where}: unknown key {key!r}{_suggest(key, MIX_KEYS)}; keys: {', '.join(MIX_KEYS)}"
        )
    if entry.get("source") not in MIX_SOURCES:
        raise ValueError(
            f"{where}.source must be one of {', '.join(MIX_SOURCES)}, got {entry.get('source')!r}"
        )
    weight = entry.get("weight")
    number = isinstance(weight, (int, float)) and not isinstance(weight, bool)
    if not number or not 0 < weight < float("inf"):
        raise ValueError(f"{where}.weight must be a positive number (a relative frequency), got {weight!r}")
    for key in ("count", "validation"):
        value = entry.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
            raise ValueError(f"{where}.{key} must be a non-negative integer, got {value!r}")
    path = entry.get("path")
    paths = [path] if isinstance(path, str) else path
    named = isinstance(paths, (list, tuple)) and bool(paths) and all(
        isinstance(p, str) and p.strip() for p in paths
    )
    if path is not None and not named:
        raise ValueError(f"{where}.path must be a path or a list of paths, got {path!r}")
    if entry["source"] == "procedural" and path is not None:
        raise ValueError(f"{where}.path is {path!r} but its source is 'procedural', which reads no files")


@dataclass(frozen=True)
class TrainSection:
    resolution: int = param(256, "training crop size in pixels")
    batch: int = param(8, "samples per step")
    epochs: int = param(20, "passes over the data")
    max_steps: int | None = param(None, "stop after this many generator steps (None: no limit)")
    max_minutes: float | None = param(None, "stop after this much training time (None: no limit)")
    renderings: int = param(9, "light/view configurations per sample for the rendering loss and D")
    seed: int = param(0, "seed of initialisation, sampling and dropout")
    log_every: int = param(10, "log losses every this many steps")
    validate_every: int = param(500, "validate every this many steps (and at the end)")
    checkpoint_every: int | None = param(
        None,
        "write the full checkpoint (OUT/last.pt) every this many steps, and at the end (None: "
        "by time only, checkpoint_minutes)",
    )
    checkpoint_minutes: float | None = param(
        10.0,
        "write the full checkpoint when this many minutes of wall time have passed since the "
        "last one (None: by steps only); a paper-size one is about 1.2 GB",
    )
    upload_minutes: float | None = param(
        60.0,
        "upload the weights (OUT/weights.pt, no optimiser state) to the MLflow run at most this "
        "often, and always at the end (None: only at the end)",
    )
    render_backend: str = param(
        "compiled",
        "renderer of the loss and discriminator renderings: compiled (torch.compile, 2-3x faster "
        "forward+backward after a compile of seconds) or eager",
        choices=("compiled", "eager"),
    )
    clock: str = param(
        "auto",
        "what max_minutes and the logged training time count: cpu (the process's CPU time over its "
        "torch threads, which other programs on the machine cannot tilt), wall, or auto (cpu on a "
        "CPU; on a GPU wall time with the GPU synchronised, i.e. GPU time)",
        choices=("auto", "cpu", "wall"),
    )
    compile: bool = param(
        False,
        "torch.compile the generator and the discriminator (a compile of tens of seconds to "
        "minutes when the fit starts)",
    )
    channels_last: bool = param(False, "keep the networks' images in NHWC memory layout for the convolutions")
    precision: str = param(
        "fp32",
        "fp32, or bf16: the networks under bfloat16 autocast (the renderer and losses stay float32)",
        choices=("fp32", "bf16"),
    )

    def __post_init__(self):
        _check(
            MIN_RESOLUTION <= self.resolution <= MAX_RESOLUTION,
            "resolution",
            self.resolution,
            f"in [{MIN_RESOLUTION}, {MAX_RESOLUTION}] pixels (and what the generator takes)",
        )
        for name in ("batch", "epochs", "renderings", "log_every", "validate_every"):
            _int_at_least(getattr(self, name), name, 1)
        _int_at_least(self.checkpoint_every, "checkpoint_every", 1, none="by time only")
        for name in ("checkpoint_minutes", "upload_minutes"):
            if getattr(self, name) is not None:
                _finite(getattr(self, name), name, positive=True)
        for name in ("compile", "channels_last"):
            _check(isinstance(getattr(self, name), bool), name, getattr(self, name), "true or false")
        _int_at_least(self.max_steps, "max_steps", 1, none="no limit")
        if self.max_minutes is not None:
            _finite(self.max_minutes, "max_minutes")  # 0: stop after the first step
        _seed(self.seed, "seed")


_SECTIONS: dict[str, type] = {
    "generator": NetworkSection,
    "discriminator": NetworkSection,
    "loss": LossSection,
    "optim": OptimSection,
    "data": DataSection,
    "train": TrainSection,
}
_TOP_LEVEL = {*_SECTIONS, "description", "base", "sizes"}


@dataclass(frozen=True)
class Recipe:
    """A resolved recipe: every field known, nothing left to defaults elsewhere."""

    name: str
    size: str
    description: str
    generator: NetworkSection
    discriminator: NetworkSection | None
    loss: LossSection
    optim: OptimSection
    data: DataSection
    train: TrainSection
    source: str

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for MLflow params and the YAML artifact); tuples become lists."""

        def plain(v):
            if dataclasses.is_dataclass(v):
                return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
            if isinstance(v, (tuple, list)):
                return [plain(x) for x in v]
            if isinstance(v, Mapping):
                return {k: plain(x) for k, x in v.items()}
            return v

        return plain(self)


# -- finding recipes ------------------------------------------------------------------------


def _entry_points() -> dict[str, list[Any]]:
    found: dict[str, list[Any]] = {}
    for ep in importlib.metadata.entry_points(group=RECIPE_GROUP):
        same = found.setdefault(ep.name, [])
        if not any(e.value == ep.value for e in same):
            same.append(ep)
    return found


def list_recipes() -> list[str]:
    """Names of the registered recipes (built-ins and plugins), sorted."""
    return sorted(_entry_points())


def recipe_path(name_or_path: str | Path) -> Path:
    """The YAML file of a registered recipe name, or the given path if it is a file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.is_file():
        if not p.is_file():
            raise RecipeError(f"{p}: recipe file not found")
        return p
    eps = _entry_points()
    entries = eps.get(str(name_or_path))
    if not entries:
        close = difflib.get_close_matches(str(name_or_path), list(eps), n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
        raise RecipeError(
            f"unknown recipe {str(name_or_path)!r}.{hint} Recipes: {', '.join(sorted(eps)) or 'none'}; "
            "or give the path of a YAML file."
        )
    if len(entries) > 1:
        who = " and ".join(f"{e.dist.name if e.dist else '?'} ({e.value})" for e in entries)
        raise RecipeError(f"recipe {name_or_path!r} is registered by {who}; uninstall or rename one")
    try:
        target = entries[0].load()
    except Exception as e:  # a plugin can fail in any way on import
        raise RecipeError(f"recipe {name_or_path!r} ({entries[0].value}) failed to load: {e}") from e
    return Path(target)


# -- reading ----------------------------------------------------------------------------------


def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml

    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise RecipeError(
            f"{path}: not UTF-8 text (byte {e.object[e.start]:#04x} at offset {e.start}); "
            "save the recipe as UTF-8"
        ) from None
    except OSError as e:
        raise RecipeError(f"{path}: cannot read the recipe ({e.strerror})") from None
    try:
        # lr: 3e-4 is a number, as with --set; duplicate keys, deep nesting and alias bombs
        # are refused here, before anything walks the document (svbrdf_render.yamlio)
        data = safe_load(text)
    except yaml.YAMLError as e:
        raise RecipeError(f"{path}: not valid YAML: {e}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise RecipeError(f"{path}: a recipe is a mapping of sections, got {type(data).__name__}")
    unknown = set(data) - _TOP_LEVEL
    if unknown:
        key = sorted(unknown)[0]
        raise RecipeError(
            f"{path}: unknown section {key!r}{_suggest(key, _TOP_LEVEL)}; "
            f"sections: {', '.join(sorted(_TOP_LEVEL))}"
        )
    return data


def _suggest(key: str, options: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, list(options), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _merge(base: dict[str, Any], top: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in top.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) and k != "config":
            out[k] = _merge(dict(out[k]), v)
        else:
            out[k] = v
    return out


def _resolve_file(path: Path, seen: tuple[Path, ...] = ()) -> tuple[dict[str, Any], dict[str, dict]]:
    """The merged sections of a recipe file and its bases, and its sizes (bases' sizes too)."""
    if path.resolve() in seen:
        chain = " -> ".join(str(p) for p in (*seen, path))
        raise RecipeError(f"{path}: recipes base on each other in a loop: {chain}")
    data = _read_yaml(path)
    sections: dict[str, Any] = {}
    sizes: dict[str, dict] = {}
    if "base" in data:
        base_path = _base_path(data["base"], path)
        sections, sizes = _resolve_file(base_path, (*seen, path.resolve()))
    own = {k: v for k, v in data.items() if k not in ("base", "sizes")}
    sections = _merge(sections, own)
    if not isinstance(data.get("sizes") or {}, Mapping):
        raise RecipeError(f"{path}: sizes must map size names to overrides, got {data['sizes']!r:.80}")
    for size, overrides in (data.get("sizes") or {}).items():
        if not isinstance(overrides, Mapping):
            raise RecipeError(f"{path}: sizes.{size} must map dotted fields to values")
        sizes[size] = {**sizes.get(size, {}), **overrides}
    return sections, sizes


def _base_path(base: Any, path: Path) -> Path:
    """The file ``base:`` names in recipe ``path``: a relative path is read from the recipe's own
    folder (wherever the command runs), a bare name is a registered recipe."""
    if not isinstance(base, str) or not base.strip():
        raise RecipeError(
            f"{path}: base: expected a recipe name or the path of a YAML file, got {base!r}"
        )
    p = Path(base).expanduser()
    if not p.is_absolute():
        beside = path.parent / p
        if beside.suffix in (".yaml", ".yml") or beside.is_file():
            if not beside.is_file():
                raise RecipeError(
                    f"{path}: base: {base!r}: no file {beside} (a relative base is read from the "
                    "folder of the recipe that names it)"
                )
            return beside
    try:
        return recipe_path(p if p.is_absolute() else base)
    except RecipeError as e:
        raise RecipeError(f"{path}: base: {e}") from None


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["loss.adv=0", "train.batch=4"]`` -> ``{"loss.adv": 0, "train.batch": 4}``; values are YAML."""
    import yaml

    out: dict[str, Any] = {}
    given: dict[str, str] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or "." not in key:
            raise RecipeError(f"--set {item!r}: expected section.field=value, e.g. --set loss.adv=0")
        key = key.strip()
        if key in given:  # the last one would win without a word
            raise RecipeError(
                f"--set {key} is given twice ({given[key]!r} and {item!r}); give each field once"
            )
        given[key] = item
        try:
            value = safe_load(raw)  # read as recipe files are: 3e-4 is a number
        except yaml.YAMLError as e:
            raise RecipeError(f"--set {item!r}: the value is not valid YAML: {e}") from None
        out[key] = value
    return out


def _apply(
    sections: dict[str, Any], overrides: Mapping[str, Any], where: str, *, skip_disabled: bool = False
) -> dict[str, Any]:
    """Dotted ``overrides`` applied to ``sections``. With ``skip_disabled`` (sizes), a section the
    recipe set to null (``discriminator: null``) stays off instead of being re-created."""
    sections = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in sections.items()}
    for dotted, value in overrides.items():
        section, _, rest = dotted.partition(".")
        if section not in _SECTIONS:
            raise RecipeError(
                f"{where}: {dotted!r}: unknown section {section!r}{_suggest(section, _SECTIONS)}"
            )
        cls = _SECTIONS[section]
        field, _, sub = rest.partition(".")
        names = [f.name for f in dataclasses.fields(cls)]
        if field not in names:
            raise RecipeError(
                f"{where}: {dotted!r}: unknown field {field!r} of section {section!r}"
                f"{_suggest(field, names)}; "
                f"fields: {', '.join(names)}"
            )
        if section in sections and sections[section] is None:
            if skip_disabled:
                continue
            sections[section] = {}
        target = sections.setdefault(section, {})
        if sub:  # into a dict field, e.g. generator.config.preset or loss.maps.normal
            inner = dict(target.get(field) or {})
            node = inner
            keys = sub.split(".")
            for k in keys[:-1]:
                node = node.setdefault(k, {})
            node[keys[-1]] = value
            target[field] = inner
        else:
            target[field] = value
    return sections


def load_recipe(
    name_or_path: str | Path, size: str = "paper", overrides: Mapping[str, Any] | None = None
) -> Recipe:
    """Read, merge and check a recipe: the file, its bases, the chosen size, then ``overrides``.

    Every size of the file is checked, not only ``size``: a bad value that the chosen size
    happens to override is still reported, naming the size it breaks. Checks cover each
    field's range, and settings that cannot work together (a resolution the generator cannot
    take, a discriminator that judges another number of renderings than the loss draws, ...),
    so that nothing fails later in the first step.

    Raises:
        RecipeError: an unknown recipe, section, field or size, or a value of the wrong type or
            out of range, naming the field, the value, the file and the size or override.
    """
    path = recipe_path(name_or_path)
    sections, sizes = _resolve_file(path)
    if size != "paper" and size not in sizes:
        raise RecipeError(
            f"{path}: no size {size!r}{_suggest(size, sizes)}; sizes: paper, {', '.join(sizes) or '(none)'}"
        )
    name = Path(path).stem if Path(str(name_or_path)).suffix else str(name_or_path)
    for other in ("paper", *sizes):
        if other != size:
            _sized(path, name, other, sections, sizes)
    recipe = _sized(path, name, size, sections, sizes)
    if overrides:
        recipe = _sized(path, name, size, sections, sizes, overrides)
    return recipe


def _sized(
    path: Path,
    name: str,
    size: str,
    sections: dict[str, Any],
    sizes: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Any] | None = None,
) -> Recipe:
    """The recipe of file ``path`` at ``size`` with ``overrides``, checked; errors say which."""
    where = f"{path} (size {size})"
    if size != "paper":
        sections = _apply(sections, sizes[size], f"{path} (sizes.{size})", skip_disabled=True)
    if overrides:
        sections = _apply(sections, overrides, f"--set (recipe {path})")
        given = ", ".join(f"{k}={_show(v)}" for k, v in overrides.items())
        where = f"{where} with {given}"

    def build(section: str):
        values = sections.get(section)
        if values is None:
            return None
        if not isinstance(values, Mapping):
            raise RecipeError(f"{where}: section {section!r} must be a mapping, got {values!r}")
        try:
            return build_config(_SECTIONS[section], values, what=f"{where}: section {section!r}")
        except ConfigError as e:
            raise RecipeError(str(e)) from None

    loss = build("loss") or LossSection()
    discriminator = build("discriminator") if "discriminator" in sections else None
    if loss.adv == 0:
        discriminator = None  # never built nor trained without an adversarial term
    recipe = Recipe(
        name=name,
        size=size,
        description=str(sections.get("description", "")),
        generator=build("generator") or NetworkSection(),
        discriminator=discriminator,
        loss=loss,
        optim=build("optim") or OptimSection(),
        data=build("data") or DataSection(),
        train=build("train") or TrainSection(),
        source=str(path),
    )
    check_recipe(recipe, where)
    return recipe


def _show(value: Any) -> str:
    return "null" if value is None else str(value)


def check_recipe(recipe: Recipe, where: str) -> None:
    """Refuse settings of ``recipe`` that are each in range but cannot work together.

    The networks are checked through svbrdf-models' own config validation (names, presets,
    fields, the attention modules a generator names) and asked which input sizes they take;
    nothing is built.

    Raises:
        RecipeError: starting with ``where`` and naming the fields.
    """
    from svbrdf_models import check_input_size

    t, d = recipe.train, recipe.data  # None only in a damaged checkpoint's recipe
    if recipe.loss is not None and recipe.loss.adv > 0 and recipe.discriminator is None:
        raise RecipeError(
            f"{where}: loss.adv is {recipe.loss.adv} but no discriminator is set; set one or loss.adv=0"
        )
    for kind, section in (("generator", recipe.generator), ("discriminator", recipe.discriminator)):
        if section is None:
            continue
        try:
            config = resolve_config(kind, section.name, section.config)
        except RegistryError as e:
            raise RecipeError(f"{where}: {kind}: {e}") from None
        if t is None:
            continue
        try:
            check_input_size(kind, section.name, section.config, t.resolution)
        except RegistryError as e:
            raise RecipeError(
                f"{where}: train.resolution is {t.resolution}, but {e}; set train.resolution to a size "
                f"the {kind} takes, or change {kind}.config"
            ) from None
        wants = getattr(config, "renderings", None) if kind == "discriminator" else None
        if wants is not None and wants != t.renderings:
            raise RecipeError(
                f"{where}: discriminator.config.renderings is {wants} but train.renderings is "
                f"{t.renderings}; the discriminator judges the renderings the loss draws: set both alike"
            )
    if d is not None and d.source == "procedural" and d.path is not None:
        raise RecipeError(
            f"{where}: data.path is {_show(d.path)} but data.source is 'procedural', which reads no files; "
            "set data.source to shards or des18 (fit --data PATH does both), or data.path=null"
        )
    if t is not None and d is not None and d.source in ("procedural", "mix") and d.count < t.batch:
        raise RecipeError(
            f"{where}: data.count is {d.count}, fewer samples per epoch than one step of train.batch "
            f"{t.batch}; raise data.count or lower train.batch"
        )


def recipe_from_dict(data: Mapping[str, Any], *, where: str = "recipe") -> Recipe:
    """The :class:`Recipe` that ``Recipe.to_dict()`` wrote (e.g. into a checkpoint).

    Raises:
        RecipeError: ``data`` is not a mapping of sections, or a section or value is wrong;
            the message starts with ``where``.
    """
    if not isinstance(data, Mapping):
        raise RecipeError(f"{where}: a recipe is a mapping of sections, got {type(data).__name__}")
    optim = data.get("optim")
    if isinstance(optim, Mapping) and "decay_every_samples" not in optim:
        # written before schedules were counted in samples: its period was in epochs
        data = {**data, "optim": {**optim, "decay_every_samples": None}}
    try:
        sections = {
            name: (None if data.get(name) is None else build_config(cls, data[name], what=f"{where}: {name}"))
            for name, cls in _SECTIONS.items()
        }
    except ConfigError as e:
        raise RecipeError(str(e)) from None
    recipe = Recipe(
        name=str(data.get("name", "recipe")),
        size=str(data.get("size", "paper")),
        description=str(data.get("description", "")),
        source=str(data.get("source", "")),
        **sections,
    )
    check_recipe(recipe, where)
    return recipe


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out or {prefix[:-1]: {}}
    return {prefix[:-1]: value}


def recipe_differences(a: Recipe, b: Recipe, ignore: Iterable[str] = ()) -> list[str]:
    """Dotted fields whose values differ between two recipes (``"loss.adv: 0.1 -> 0.0"``).

    ``ignore`` lists dotted prefixes to leave out (e.g. ``"train.max_steps"``); the recipe's
    name, size, description and source file are not compared.
    """
    fa, fb = _flat(a.to_dict()), _flat(b.to_dict())
    skip = ("name", "size", "description", "source", *ignore)
    out = []
    for key in sorted(set(fa) | set(fb)):
        if any(key == p or key.startswith(p + ".") for p in skip):
            continue
        if fa.get(key, "(unset)") != fb.get(key, "(unset)"):
            out.append(f"{key}: {fa.get(key, '(unset)')!r} -> {fb.get(key, '(unset)')!r}")
    return out


def with_overrides(recipe: Recipe, overrides: Mapping[str, Any], where: str = "--set") -> Recipe:
    """``recipe`` with dotted ``overrides`` applied (as ``--set`` does), checked again."""
    if not overrides:
        return recipe
    data = recipe.to_dict()
    meta = {k: data.pop(k) for k in ("name", "size", "description", "source")}
    recipe_name = f"recipe {meta['source'] or meta['name']}"
    sections = _apply(data, overrides, f"{where} ({recipe_name})")
    given = ", ".join(f"{k}={_show(v)}" for k, v in overrides.items())
    return recipe_from_dict({**sections, **meta}, where=f"{where} {given} ({recipe_name})")
