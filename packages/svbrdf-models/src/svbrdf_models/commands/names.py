"""``svbrdf-models list`` and ``describe``: the registered generators, attention modules and
discriminators, where they come from, how to configure them and what they cost on this CPU."""

from __future__ import annotations

import argparse
import difflib
import statistics
import time

from svbrdf_render.plumbing import int_range

from .._registry import _NOUNS, KINDS, REINSTALL_HINT, Registry
from ..errors import RegistryError, UnknownNameError

__all__ = ["add_list", "add_describe", "run_list", "run_describe"]

#: Bounds of --channels (a 4096-channel 256x256 input is 1 GiB) and --repeats.
MAX_CHANNELS, MAX_REPEATS = 4096, 1000
DEFAULT_CHANNELS, DEFAULT_REPEATS = 64, 3

EPILOG_LIST = """\
examples:
  svbrdf-models list                         # every registered name, its package and description
  svbrdf-models list --kind attention
  svbrdf-models list --kind generator --detail              # + parameters and CPU time at 256x256
  svbrdf-models list --kind generator --detail --preset small

--detail builds each network (with --preset where it has one) and times inference on one
256x256 input on this machine's CPU: generators take a photo (1, 3, 256, 256); attention
modules a feature map (1, --channels, 256, 256); discriminators the renderings or maps of one
256x256 material. The figure is the median of --repeats runs after one warm-up.
"""

EPILOG_DESCRIBE = """\
examples:
  svbrdf-models describe ours               # config fields, defaults and presets
  svbrdf-models describe multiscale --kind attention

Fields can be set from Python (create_generator("ours", {"depth": 6})) or a recipe's YAML.
"""


def add_list(sub) -> None:
    """The ``list`` sub-command and its options."""
    p = sub.add_parser(
        "list",
        help="registered names with their source package",
        description="List registered names with their source package and description.",
        epilog=EPILOG_LIST,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--kind", choices=list(KINDS), action="append", help="only this kind (repeatable; default: all three)"
    )
    p.add_argument("--pattern", default="*", help="shell-style name filter, e.g. 'c*' (default: *)")
    p.add_argument(
        "--detail", action="store_true", help="also parameter count and CPU inference time at 256x256"
    )
    p.add_argument(
        "--preset", default=None, help="with --detail: preset to build where one exists (e.g. small)"
    )
    p.add_argument(
        "--channels",
        type=int_range(1, MAX_CHANNELS),
        default=None,
        help=f"with --detail: input channels for attention modules, 1 to {MAX_CHANNELS} "
        f"(default: {DEFAULT_CHANNELS})",
    )
    p.add_argument(
        "--repeats",
        type=int_range(1, MAX_REPEATS),
        default=None,
        help=f"with --detail: timed runs per network, 1 to {MAX_REPEATS} (default: {DEFAULT_REPEATS})",
    )


def add_describe(sub) -> None:
    """The ``describe`` sub-command and its options."""
    p = sub.add_parser(
        "describe",
        help="config fields, defaults and presets of one name",
        description="Show where a registered name comes from and how to configure it.",
        epilog=EPILOG_DESCRIBE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("name")
    p.add_argument("--kind", choices=list(KINDS), help="needed only when the name exists in several kinds")


def run_list(args, registry: Registry, out) -> None:
    kinds = list(dict.fromkeys(args.kind or KINDS))
    _check_list_flags(args, registry, kinds)
    args.channels = args.channels or DEFAULT_CHANNELS
    args.repeats = args.repeats or DEFAULT_REPEATS
    header = f"{'kind':<14} {'name':<14} {'source':<24}"
    if args.detail:
        header += f" {'params':>10} {'CPU ms':>9}"
    print(header + "  description", file=out)
    for kind in kinds:
        for name in registry.names(kind, args.pattern):
            print(_row(registry, kind, name, args), file=out, flush=True)


def _check_list_flags(args, registry: Registry, kinds: list[str]) -> None:
    """Refuse flags that would have no effect: --detail's options without it, a --channels no
    listed kind reads, a --preset no listed network has, a --pattern that matches nothing."""
    flags = ("preset", "channels", "repeats")
    given = [f"--{n} {getattr(args, n)}" for n in flags if getattr(args, n) is not None]
    if given and not args.detail:
        raise RegistryError(f"{', '.join(given)}: only --detail builds and times networks; add --detail")
    names = {kind: registry.names(kind, args.pattern) for kind in kinds}
    if not any(names.values()):
        raise UnknownNameError(
            f"--pattern {args.pattern!r} matches no registered {' or '.join(_NOUNS[k] for k in kinds)}; "
            f"'svbrdf-models list' shows every name. {REINSTALL_HINT}"
        )
    if args.channels is not None and not names.get("attention"):
        raise RegistryError(
            f"--channels {args.channels}: only attention modules take it, and none is listed "
            "(add --kind attention)"
        )
    if args.preset is not None:
        has = set()
        for kind, listed in names.items():
            for name in listed:
                try:
                    has.update(registry.spec(kind, name).presets)
                except RegistryError:
                    continue  # listed with its error
        if args.preset not in has:
            close = difflib.get_close_matches(args.preset, sorted(has), n=2, cutoff=0.5)
            hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
            raise RegistryError(
                f"--preset {args.preset!r}: no listed network has it.{hint} "
                f"Presets: {', '.join(sorted(has)) or 'none'}."
            )


def _row(registry: Registry, kind: str, name: str, args) -> str:
    sources = registry.sources(kind, name)
    source = ", ".join(sources)
    row = f"{kind:<14} {name:<14} {source:<24}"
    try:
        spec = registry.spec(kind, name)
    except RegistryError as e:
        pad = f" {'-':>10} {'-':>9}" if args.detail else ""
        reason = "registered twice; creating it is an error" if len(sources) > 1 else f"FAILED TO LOAD: {e}"
        return f"{row}{pad}  {reason}"
    if args.detail:
        try:
            params, ms = _measure(registry, kind, name, args)
            row += f" {_count(params):>10} {ms:>9.1f}"
        except (RegistryError, RuntimeError, ValueError) as e:
            row += f" {'-':>10} {'-':>9}"
            return f"{row}  {spec.description} (could not time: {e})"
    return f"{row}  {spec.description}"


def _count(n: int) -> str:
    if n < 1000:
        return str(n)
    return f"{n / 1e3:.1f}k" if n < 1e6 else f"{n / 1e6:.2f}M"


def _measure(registry: Registry, kind: str, name: str, args) -> tuple[int, float]:
    import torch

    from svbrdf_render import SVBRDF

    spec = registry.spec(kind, name)
    config = {"preset": args.preset} if args.preset and args.preset in spec.presets else {}
    size = 256
    if kind == "attention":
        module = registry.create(kind, name, config, channels=args.channels)
        inputs = ((torch.rand(1, args.channels, size, size),), {})
    else:
        module = registry.create(kind, name, config)
        if kind == "generator":
            inputs = ((torch.rand(1, 3, size, size),), {})
        else:  # discriminators read renderings or maps: give both, sized as the config asks
            n = getattr(getattr(module, "config", None), "renderings", 9)
            inputs = ((), {"maps": SVBRDF.constant(1, size), "renderings": torch.rand(1, n, 3, size, size)})
    module.eval()
    params = sum(p.numel() for p in module.parameters())
    times = []
    with torch.inference_mode():
        for i in range(args.repeats + 1):
            t0 = time.perf_counter()
            module(*inputs[0], **inputs[1])
            if i:  # the first run warms up allocators and kernels
                times.append((time.perf_counter() - t0) * 1e3)
    return params, statistics.median(times)


def run_describe(args, registry: Registry, out) -> None:
    kinds = [args.kind] if args.kind else [k for k in KINDS if args.name in registry.names(k)]
    if not kinds:
        every = [n for k in KINDS for n in registry.names(k)]
        close = difflib.get_close_matches(args.name, every, n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(map(repr, close))}?" if close else ""
        raise UnknownNameError(
            f"no generator, attention module or discriminator is named {args.name!r}.{hint} "
            f"'svbrdf-models list' shows what is installed. {REINSTALL_HINT}"
        )
    if len(kinds) > 1:
        raise RegistryError(
            f"{args.name!r} is registered as {' and '.join(_NOUNS[k] for k in kinds)}; pick one with --kind"
        )
    print(registry.describe(kinds[0], args.name).format(), file=out)
