"""The effects a scene may declare, with their parameters and defaults.

An effect that a scene does not declare is *absent* from the computation: the renderer
builds a stage only for what is declared (see :mod:`svbrdf_render.renderer`).

=============  =======  ====================================================================
effect         phase    parameters (defaults)
=============  =======  ====================================================================
diffuse        shading  \u2014 : Lambert term ``d (1 - s) / pi``
specular       shading  ``alpha_min`` (1e-3), ``alpha_floor`` ("remap" | "clamp"): GGX lobe
                        ``D V F / 4``
fresnel        shading  ``model`` ("des18" | "schlick"); absent: ``F = s``
masking        shading  ``model`` ("schlick-ggx" | "smith" | "height-correlated");
                        absent: ``V = 1``
cosine         light    \u2014 : multiply by ``max(n.l, 0)``
falloff        light    ``min_distance`` (1e-3): divide by the squared distance to point
                        lights (directional lights are unaffected)
vignetting     image    ``strength`` (1.0): ``1 - strength (1 - cos^4 theta)`` with theta
                        the angle of a pixel off the camera axis
exposure       image    ``ev`` (0.0): multiply by ``2**ev``
noise          image    ``sigma`` (0.01), ``shot`` (0.0), ``seed`` (0): Gaussian read noise
                        plus signal-dependent shot noise, variance ``sigma^2 + shot x``
clip           image    ``max`` (1.0): clamp to ``[0, max]`` (sensor saturation)
gamma          image    ``gamma`` (2.2): ``x ** (1/gamma)`` after clamping at 1e-8
=============  =======  ====================================================================

Image effects run in the order of this table, whatever the order of declaration.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .brdf import ALPHA_MIN, FRESNEL_MODELS, MASKING_MODELS
from .errors import SceneError

__all__ = [
    "EffectSpec",
    "EFFECTS",
    "DES18_EFFECTS",
    "PHOTO_EFFECTS",
    "resolve_effects",
    "effect_names",
]


@dataclass(frozen=True)
class EffectSpec:
    """What an effect is called, where it acts and which parameters it takes."""

    name: str
    phase: str  # "shading" | "light" | "image"
    defaults: Mapping[str, Any] = field(default_factory=dict)
    choices: Mapping[str, tuple] = field(default_factory=dict)
    doc: str = ""


def _spec(name, phase, doc, choices=None, **defaults) -> EffectSpec:
    return EffectSpec(name, phase, dict(defaults), dict(choices or {}), doc)


#: The registry, in pipeline order. Tests remove entries to build "a renderer that never
#: heard of" an effect; nothing else mutates it.
EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in [
        _spec("diffuse", "shading", "Lambert term d (1 - s) / pi"),
        _spec(
            "specular",
            "shading",
            "GGX lobe D V F / 4",
            choices={"alpha_floor": ("remap", "clamp")},
            alpha_min=ALPHA_MIN,
            alpha_floor="remap",
        ),
        _spec("fresnel", "shading", "Fresnel factor", choices={"model": FRESNEL_MODELS}, model="des18"),
        _spec(
            "masking",
            "shading",
            "shadowing-masking",
            choices={"model": MASKING_MODELS},
            model="schlick-ggx",
        ),
        _spec("cosine", "light", "max(n.l, 0)"),
        _spec("falloff", "light", "inverse-square distance", min_distance=1e-3),
        _spec("vignetting", "image", "cos^4 lens falloff", strength=1.0),
        _spec("exposure", "image", "gain 2**ev", ev=0.0),
        _spec("noise", "image", "seeded sensor noise", sigma=0.01, shot=0.0, seed=0),
        _spec("clip", "image", "saturation to [0, max]", max=1.0),
        _spec("gamma", "image", "display encoding x**(1/gamma)", gamma=2.2),
    ]
}

#: The Deschaintre 2018 rendering: what reproduces the Des18 data set inputs.
DES18_EFFECTS = ("diffuse", "specular", "fresnel", "masking", "cosine", "falloff")
#: A simulated phone photo: Des18 shading plus exposure, vignetting, noise and clipping.
PHOTO_EFFECTS = DES18_EFFECTS + ("vignetting", "exposure", "noise", "clip")


def effect_names() -> tuple[str, ...]:
    return tuple(EFFECTS)


def _unknown(what: str, name: str, known) -> SceneError:
    close = difflib.get_close_matches(name, list(known), n=3)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return SceneError(f"unknown {what} {name!r}{hint} Known: {', '.join(known)}")


def resolve_effects(effects) -> dict[str, dict[str, Any]]:
    """Normalise a declaration to ``{name: {param: value}}`` with defaults filled in.

    Accepts a list of names, a mapping ``name -> params`` (``None``/``{}``/``True`` for
    defaults), or a mix. The result is ordered as the pipeline runs.
    """
    if effects is None:
        return {}
    if isinstance(effects, str):
        raise SceneError(
            f"effects: expected a list of names or a mapping, got the string {effects!r}"
        )
    if isinstance(effects, Mapping):
        items = list(effects.items())
    else:
        items = []
        for e in effects:
            if isinstance(e, str):
                items.append((e, None))
            elif isinstance(e, Mapping) and len(e) == 1:
                items.extend(e.items())
            else:
                raise SceneError(f"effects: expected a name or a one-key mapping, got {e!r}")
    declared: dict[str, dict[str, Any]] = {}
    for name, params in items:
        if name not in EFFECTS:
            raise _unknown("effect", name, EFFECTS)
        spec = EFFECTS[name]
        if params is False:
            continue
        if params is None or params is True:
            params = {}
        if not isinstance(params, Mapping):
            raise SceneError(f"effect {name!r}: expected a mapping of parameters, got {params!r}")
        resolved = dict(spec.defaults)
        for key, value in params.items():
            if key not in spec.defaults:
                if spec.defaults:
                    raise _unknown(f"parameter of effect {name!r}:", key, spec.defaults)
                raise SceneError(f"effect {name!r} takes no parameters, got {key!r}")
            default = spec.defaults[key]
            if key in spec.choices:
                if value not in spec.choices[key]:
                    raise SceneError(
                        f"effect {name!r}: {key} must be one of {spec.choices[key]}, got {value!r}"
                    )
            elif isinstance(default, int):
                if isinstance(value, bool) or not isinstance(value, int):
                    raise SceneError(f"effect {name!r}: {key} must be an integer, got {value!r}")
            elif isinstance(default, float):
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise SceneError(f"effect {name!r}: {key} must be a number, got {value!r}")
                value = float(value)
            resolved[key] = value
        _check_ranges(name, resolved)
        declared[name] = resolved
    if "fresnel" in declared and "specular" not in declared or (
        "masking" in declared and "specular" not in declared
    ):
        raise SceneError(
            "effects: 'fresnel' and 'masking' modify the specular lobe; declare 'specular' too"
        )
    return {name: declared[name] for name in EFFECTS if name in declared}


def _check_ranges(name: str, p: dict[str, Any]) -> None:
    def need(cond: bool, what: str):
        if not cond:
            raise SceneError(f"effect {name!r}: {what}")

    if name == "specular":
        need(0 < p["alpha_min"] < 1, f"alpha_min must be in (0, 1), got {p['alpha_min']}")
    elif name == "falloff":
        need(p["min_distance"] > 0, f"min_distance must be > 0, got {p['min_distance']}")
    elif name == "vignetting":
        need(0 <= p["strength"] <= 1, f"strength must be in [0, 1], got {p['strength']}")
    elif name == "noise":
        need(p["sigma"] >= 0 and p["shot"] >= 0, "sigma and shot must be >= 0")
    elif name == "clip":
        need(p["max"] > 0, f"max must be > 0, got {p['max']}")
    elif name == "gamma":
        need(p["gamma"] > 0, f"gamma must be > 0, got {p['gamma']}")
