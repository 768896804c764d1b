"""``svbrdf-models show``: what a trained model file holds and how it was made."""

from __future__ import annotations

import argparse

from .._registry import Registry

__all__ = ["add_parser", "run"]

EPILOG_SHOW = """\
examples:
  svbrdf-models show                        # the model shipped with svbrdf-models
  svbrdf-models show ours.pt                # a file svbrdf-train export wrote
  svbrdf-models show models:/svbrdf-ours/2  # from the MLflow model registry (needs mlflow)

Prints the generator and its config, the training resolution, steps, time, hardware and data
(with the real files it learnt), the code revision, the figures recorded with it and the
file's SHA-256. Loading checks the file fully: every field of its header (one line naming
the field otherwise), its size once unpacked, a NAME.sha256 beside it (which must match),
the network's size before it is built, and the weights (finite, fitting the generator).
A URL is downloaded once into torch.hub's cache (TORCH_HOME) and kept only when its SHA-256
matches its name and it loads; a server silent for SVBRDF_DOWNLOAD_TIMEOUT seconds (default
30) is given up on.
"""


def add_parser(sub) -> None:
    """The ``show`` sub-command and its options."""
    p = sub.add_parser(
        "show",
        help="what a trained model file holds: generator, training, data, figures",
        description="Load a trained model file and say what it is and how it was made.",
        epilog=EPILOG_SHOW,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "source",
        nargs="?",
        default="pretrained",
        help="a model file, an https URL (NAME-HEX.pt), models:/NAME/VERSION, runs:/ID/PATH, or "
        "pretrained[:NAME] (default: the model shipped with this package)",
    )


def run(args, registry: Registry, out) -> None:
    from ..modelfile.files import PRETRAINED, card_path, load_model

    model = load_model(args.source)
    info = model.provenance
    lines = [model.describe(), f"  SHA-256     {model.sha256}"]
    lines.append("  config      " + ", ".join(f"{k}={v}" for k, v in model.config.items()))
    lines.append(
        f"  recipe      {info.get('recipe')} ({info.get('size')}), code {info.get('git_sha', 'unknown')}"
    )
    lines.append(
        f"  training    {model.steps} steps, {info.get('samples', '?')} samples, "
        f"{float(info.get('train_seconds', 0)) / 3600:.2f} h on {info.get('hardware', 'unknown')}"
    )
    for source in (info.get("data") or {}).get("sources", []):
        files = source.get("files") or []
        where = f" {', '.join(source.get('path', []))} ({len(files)} files)" if "path" in source else ""
        weight = f" weight {source['weight']}" if "weight" in source else ""
        lines.append(f"  data        {source['source']}{weight}{where}")
    for key, value in sorted(model.metrics.items()):
        lines.append(f"  metric      {key} = {value:.4g}")
    for name, effect in (info.get("half_effect") or {}).items():
        lines.append(f"  fp16 effect {name}: RMSE {effect['rmse']:.1e}, max {effect['max']:.1e}")
    if model.source == f"pretrained:{PRETRAINED}":
        lines.append(f"  card        {card_path()}")
    print("\n".join(lines), file=out)
