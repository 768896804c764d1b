"""The recipe's ``data`` section: where training samples come from and how they are
photographed (its fields, their ranges, and ``setup``, which builds the data sets)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from svbrdf_models import param

from .values import MAX_SAMPLES, _int_at_least, _samples, _seed, suggest

if TYPE_CHECKING:  # annotations only
    from torch.utils.data import Dataset

__all__ = ["CAPTURES", "BALANCES", "MIX_KEYS", "MIX_SOURCES", "DataSection"]

#: The named photo captures of procedural data (``data.capture``;
#: svbrdf_train.data.simulated_photo's ``CAPTURE_PRESETS``).
CAPTURES = ("des18", "phone", "handheld")
#: How ``data.balance`` draws a materials source: each material alike, or by kind
#: (svbrdf_train.data.real.kinds.kind_weights).
BALANCES = ("none", "kind")
#: Keys of one ``data.mix`` entry, and the sources an entry may name.
MIX_KEYS = ("source", "weight", "path", "count", "validation", "fold", "capture")
MIX_SOURCES = ("procedural", "shards", "des18", "materials")


@dataclass(frozen=True)
class DataSection:
    source: str = param(
        "procedural",
        "procedural (generated), shards (HDF5 files), des18 (a folder of strips), materials (a "
        "folder of map-only strips normal | diffuse | roughness | specular, or a strip shard: "
        "random windows, turns and mirrors, photographed on the fly under data.capture) or mix "
        "(the sources of data.mix, drawn at random with their weights)",
        choices=("procedural", "shards", "des18", "materials", "mix"),
    )
    path: str | tuple[str, ...] | None = param(
        None,
        "shard file(s) or Des18 folder (--data); unused for procedural; for mix, the path of the "
        "entries that give none",
    )
    count: int = param(
        200_000,
        "procedural samples per epoch (the paper trains on ~200k); for mix, samples per epoch "
        "drawn from all sources; at most 10**8 (recipe.values.MAX_SAMPLES), as is validation",
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
        "with source mix: entries {source, weight[, path, count, validation, fold, capture]}; each "
        "training sample comes from entry i with probability weight_i / sum(weights); validation sets "
        "are each entry's own, put together; an entry's capture (procedural and materials) "
        "photographs its samples its own way, so that one fit sees several captures",
    )
    fold: str | None = param(
        None,
        "for materials: the materials held out of training and validated on (val_fold/): k/n "
        "(fold k of n, each material's fold fixed by a hash of its name) or comma-separated "
        "names; None: train on all of them",
    )
    capture: str = param(
        "des18",
        "how procedural materials and material strips are photographed (training and validation "
        "alike): des18 (a "
        "flash at 1.8-2.75 whose irradiance follows the distance, +-0.75 EV, linear, as the "
        "Des18 inputs) or phone (the flashes fitted to real phone photos: distance 1.8-3.7 and "
        "intensity 10-21 drawn independently, white balance within 8%, half of the photos "
        "JPEG-compressed at quality 75-95) or handheld (phone, plus the LED beside the lens with "
        "a cone-shaped beam, the camera up to 0.6 half-widths off-centre, vignetting, a residual "
        "tone curve and exposure measured against real phone photos: "
        "svbrdf_train.data.simulated_photo.CAPTURE_PRESETS)",
        choices=CAPTURES,
    )
    balance: str = param(
        "none",
        "how a materials source draws its materials: none (each alike) or kind (by the kind read "
        "from each name, brick, wood, stone, ...: each material 1/sqrt(n) of its kind's n, so rare "
        "kinds are drawn far more often than their count; svbrdf_train.data.real.kinds)",
        choices=BALANCES,
    )
    albedo_prior: tuple[float, float] | None = param(
        None,
        "for materials: [median, sigma]: scale each sample's diffuse towards a mean luminance drawn "
        "log-normally around median (sigma in natural-log units; factor 0.5-2, never above the "
        "ceiling) instead of +-25%, so the brightness mix follows the prior, not the sources' "
        "level; None: +-25%",
    )

    def __post_init__(self):
        _samples(self.count, "count", 1)
        self._check_material_draws()
        _samples(self.validation, "validation", 0)
        _int_at_least(self.workers, "workers", 0)
        _seed(self.seed, "seed")
        paths = (self.path,) if isinstance(self.path, str) else self.path or ()
        if any(not p.strip() for p in paths) or self.path == ():
            raise ValueError(f"path must name files or folders (or be null), got {self.path!r}")
        if self.real_validation is not None and not self.real_validation.strip():
            raise ValueError(
                f"real_validation must name a folder or shards (or be null), got {self.real_validation!r}"
            )
        if self.fold is not None and not str(self.fold).strip():
            raise ValueError(f"fold must be k/n or material names (or null), got {self.fold!r}")
        if self.source == "mix":
            if not self.mix:
                raise ValueError("source 'mix' needs data.mix: a list of {source, weight} entries")
            for i, entry in enumerate(self.mix):
                _check_mix_entry(i, entry)
        elif self.mix:
            raise ValueError(f"data.mix is set but data.source is {self.source!r}; set data.source=mix")

    def _check_material_draws(self) -> None:
        if self.albedo_prior is not None:
            prior = tuple(self.albedo_prior)
            numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in prior)
            ok = len(prior) == 2 and numbers
            if not (ok and 0 < prior[0] < 1 and 0 <= prior[1] <= 3):
                raise ValueError(
                    f"albedo_prior must be [median, sigma] with median in (0, 1) and sigma in [0, 3], "
                    f"got {self.albedo_prior!r}"
                )
        if self.balance == "none" and self.albedo_prior is None:
            return
        sources = [e.get("source") for e in self.mix or ()] if self.source == "mix" else [self.source]
        if "materials" not in sources:
            raise ValueError(
                "balance and albedo_prior act on a materials source; this data section has none "
                f"(source {self.source!r}): set data.source=materials or add a materials entry to data.mix"
            )

    def setup(self, resolution: int) -> tuple[Dataset, Dataset]:
        """``(train, validation)``: the data sets this section describes, at ``resolution``
        pixels (:func:`svbrdf_train.data.fitdata.section_datasets`; ``DataError`` when a source is
        missing or too small)."""
        from ..data.fitdata import section_datasets

        return section_datasets(self, resolution)


def _check_mix_entry(i: int, entry: Mapping[str, Any]) -> None:
    where = f"mix[{i}]"
    unknown = set(entry) - set(MIX_KEYS)
    if unknown:
        key = sorted(unknown)[0]
        raise ValueError(f"{where}: unknown key {key!r}{suggest(key, MIX_KEYS)}; keys: {', '.join(MIX_KEYS)}")
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
        if value is not None and value > MAX_SAMPLES:
            raise ValueError(f"{where}.{key} must be at most {MAX_SAMPLES:_} samples, got {value!r}")
    path = entry.get("path")
    paths = [path] if isinstance(path, str) else path
    named = (
        isinstance(paths, (list, tuple))
        and bool(paths)
        and all(isinstance(p, str) and p.strip() for p in paths)
    )
    if path is not None and not named:
        raise ValueError(f"{where}.path must be a path or a list of paths, got {path!r}")
    fold = entry.get("fold")
    if fold is not None and (entry["source"] != "materials" or not isinstance(fold, str) or not fold.strip()):
        raise ValueError(
            f"{where}.fold must be k/n or material names, on a materials entry only; got {fold!r}"
        )
    capture = entry.get("capture")
    photographed = entry["source"] in ("procedural", "materials")
    if capture is not None and (capture not in CAPTURES or not photographed):
        raise ValueError(
            f"{where}.capture must be one of {', '.join(CAPTURES)}, on a procedural or materials entry only "
            f"(the others bring their own photos); got {capture!r} on {entry['source']!r}"
        )
    if entry["source"] == "procedural" and path is not None:
        raise ValueError(f"{where}.path is {path!r} but its source is 'procedural', which reads no files")
