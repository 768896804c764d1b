"""The built-in recipes: YAML files beside this module, registered under ``svbrdf.recipes``.

Each constant is the path an entry point names; ``svbrdf_train.recipe.load_recipe`` reads it.
"""

from pathlib import Path

_HERE = Path(__file__).resolve().parent

__all__ = [
    "OURS",
    "NO_ATTN",
    "NO_ATTN_WIDE",
    "NO_ADV",
    "NO_SVBRDF",
    "MULTIGAN",
    "RADN",
    "OURS_REAL",
    "OURS_MIX",
    "OURS_FINETUNE",
    "OURS_GENERAL",
    "OURS_MATERIALS",
]

OURS = _HERE / "ours.yaml"
NO_ATTN = _HERE / "no-attn.yaml"
NO_ATTN_WIDE = _HERE / "no-attn-wide.yaml"
NO_ADV = _HERE / "no-adv.yaml"
NO_SVBRDF = _HERE / "no-svbrdf.yaml"
MULTIGAN = _HERE / "multigan.yaml"
RADN = _HERE / "radn.yaml"
OURS_REAL = _HERE / "ours-real.yaml"
OURS_MIX = _HERE / "ours-mix.yaml"
OURS_FINETUNE = _HERE / "ours-finetune.yaml"
OURS_GENERAL = _HERE / "ours-general.yaml"
OURS_MATERIALS = _HERE / "ours-materials.yaml"
