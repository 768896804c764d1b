"""svbrdf-models: the networks, a trained generator as a file, and the photo tool.

- :mod:`svbrdf_models.networks`: generators, attention modules, discriminators and the untrained
  baselines, in a registry that plugins extend;
- :mod:`svbrdf_models.capture`: the photo tool (``svbrdf-models predict``): one photo, batches,
  shots of the printed frame, calibrated sets, the material folder;
- :mod:`svbrdf_models.modelfile`: saving, loading and checking a trained generator (files, URLs,
  MLflow URIs, the shipped ``pretrained`` models), the MLflow model and ``svbrdf-models serve``;
- :mod:`svbrdf_models.commands`: one module per command line command.

Public API (timm style: list, describe, create)::

    import svbrdf_models as sm
    sm.list_models("generator")                 # ['no-attn', 'ours', 'unet', ...]
    sm.describe("generator", "ours").fields     # config fields with defaults and docs
    g = sm.create_generator("ours", {"preset": "small", "attention": "cbam"})
    maps = g(photo)                             # photo (B, 3, H, W) -> svbrdf_render.SVBRDF
    model = sm.load_model("pretrained")         # trained weights (a file, URL or MLflow URI)
    maps = model.predict(photo)                 # linear photo (3, H, W) -> maps at its resolution
    maps = model.predict(photo, refine=100)     # + refined against the photo at the photo's size
    d = sm.create_discriminator("patchgan", {"renderings": 9})
    logits = d(maps=maps, renderings=svbrdf_render.render(maps, scene))

A plugin registers a :class:`ModelSpec` under one of the entry-point groups
``svbrdf.generators``, ``svbrdf.attention`` or ``svbrdf.discriminators``; the built-ins use
the same groups. Nothing is imported until a name is described or created.

The photo tool (``svbrdf-models predict``, :mod:`svbrdf_models.capture.one`) needs the ``photo``
extra (``pip install svbrdf-models[photo]``: Pillow, pypng and PyYAML through svbrdf-render).
"""

from __future__ import annotations

import importlib

from ._config import FieldInfo, build_config, config_to_dict, param
from ._registry import (
    KINDS,
    ModelInfo,
    ModelSpec,
    Registry,
    check_input_size,
    create,
    create_attention,
    create_discriminator,
    create_generator,
    default_registry,
    describe,
    list_models,
    resolve_config,
)
from .errors import (
    ConfigError,
    DataError,
    DuplicateNameError,
    ModelFileError,
    PluginLoadError,
    RegistryError,
    UnknownNameError,
)

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.2.0"

# The built-in networks load on first access, like any plugin.
_LAZY = {
    "UNetGenerator": "networks.generators",
    "GeneratorConfig": "networks.generators",
    "maps_from_output": "networks.generators",
    "encode_photo": "networks.generators",
    "AttentionModule": "networks.attention",
    "MultiScaleAttention": "networks.attention",
    "PatchGAN": "networks.discriminators",
    "PatchGANDiscriminator": "networks.discriminators",
    "TrainedModel": "modelfile",
    "load_model": "modelfile",
    "save_model": "modelfile",
    "model_dict": "modelfile",
    "pretrained_path": "modelfile",
    "square_photo": "capture.photos",
    "PRETRAINED": "modelfile",
    "MultiGANDiscriminator": "networks.discriminators",
    "load_photo": "capture.photos",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'svbrdf_models' has no attribute {name!r}")


__all__ = [
    "KINDS",
    "ConfigError",
    "DataError",
    "DuplicateNameError",
    "FieldInfo",
    "ModelFileError",
    "ModelInfo",
    "ModelSpec",
    "PluginLoadError",
    "Registry",
    "RegistryError",
    "UnknownNameError",
    "build_config",
    "check_input_size",
    "config_to_dict",
    "create",
    "create_attention",
    "create_discriminator",
    "create_generator",
    "default_registry",
    "describe",
    "list_models",
    "param",
    "resolve_config",
    *_LAZY,
]

# Modules that moved into subpackages (issue 38): the old names import the new modules with a
# DeprecationWarning until release _MOVED_UNTIL (svbrdf_render.plumbing.moved; CHANGELOG.md).
#: The release that removes the old names below (0.2.0 keeps them, with a warning).
_MOVED_UNTIL = "0.3.0"
_MOVED = {
    "svbrdf_models.generators": "svbrdf_models.networks.generators",
    "svbrdf_models.attention": "svbrdf_models.networks.attention",
    "svbrdf_models.discriminators": "svbrdf_models.networks.discriminators",
    "svbrdf_models.baselines": "svbrdf_models.networks.baselines",
    "svbrdf_models.trained": "svbrdf_models.modelfile.trained",
    "svbrdf_models.modelcheck": "svbrdf_models.modelfile.modelcheck",
    "svbrdf_models.download": "svbrdf_models.modelfile.download",
    "svbrdf_models.pyfunc": "svbrdf_models.modelfile.pyfunc",
    "svbrdf_models.batch": "svbrdf_models.capture.batch",
    "svbrdf_models.photos": "svbrdf_models.capture.photos",
    "svbrdf_models.tiles": "svbrdf_models.capture.tiles",
    "svbrdf_models.refining": "svbrdf_models.capture.refining",
    "svbrdf_models.relight": "svbrdf_models.capture.relight",
    "svbrdf_models.figures": "svbrdf_models.capture.figures",
    "svbrdf_models.material": "svbrdf_models.capture.material",
    "svbrdf_models.progress": "svbrdf_render.plumbing.progress",
}

from svbrdf_render.plumbing.moved import install as _install_moved

_install_moved(_MOVED, _MOVED_UNTIL)
