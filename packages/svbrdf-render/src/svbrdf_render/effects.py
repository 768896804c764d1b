"""The effects a scene may declare: one registry, each effect declared once.

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
beam           light    ``exponent`` (2.0): a flash's soft beam, ``cos^exponent`` of the angle
                        between the ray to a pixel and the light's axis (aimed at the patch
                        centre); directional lights are unaffected
vignetting     image    ``strength`` (1.0): ``1 - strength (1 - cos^4 theta)`` with theta
                        the angle of a pixel off the camera axis
exposure       image    ``ev`` (0.0): multiply by ``2**ev``
noise          image    ``sigma`` (0.01), ``shot`` (0.0), ``seed`` (0): Gaussian read noise
                        plus signal-dependent shot noise, variance ``sigma^2 + shot x``
clip           image    ``max`` (1.0): clamp to ``[0, max]`` (sensor saturation)
tone           image    ``power`` (1.0), ``shoulder`` (0.0): a phone's tone curve as it is left
                        in a linearised photo, ``y = x**power`` then the highlight roll-off
                        ``y (1 + shoulder) / (1 + shoulder y)`` (0 and 1 stay put)
gamma          image    ``gamma`` (2.2): ``x ** (1/gamma)`` after clamping at 1e-8
=============  =======  ====================================================================

Effects of a phase run in the order of this table, whatever the order of declaration.

Adding an effect is one :func:`_register` call below its stage builder, plus its tests. A
stage builder takes the effect's resolved parameters and the whole resolved declaration
and returns the stage, whose form its phase fixes:

- ``shading``: ``prepare(surface) -> term(light) -> Tensor``, a term of the BRDF (the terms
  are summed); ``prepare`` runs once per render, ``term`` once per light.
- ``light``: ``factor(radiance, surface, light) -> radiance``, per light, after the BRDF
  times the light's radiance.
- ``image``: ``stage(x, geometry, generator) -> x`` on the summed radiance; ``geometry`` (the
  :class:`~svbrdf_render.stages.SceneGeometry`: surface positions and camera) is read only by
  effects declared ``needs_camera``, and is None where :func:`~svbrdf_render.apply_image_effects`
  runs the stages without a scene.

An effect without a stage builder is a parameter of the effect it ``requires``: fresnel
and masking choose the ``F`` and ``V`` factors of the specular lobe, which reads them.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import torch
from torch import Tensor

from . import brdf
from .brdf import ALPHA_MIN, FRESNEL_MODELS, MASKING_MODELS
from .errors import SceneError
from .geometry import cross_norm_sq, dot, toward, unit_and_sq

__all__ = [
    "EffectSpec",
    "EFFECTS",
    "PHASES",
    "DES18_EFFECTS",
    "PHOTO_EFFECTS",
    "Surface",
    "LightPath",
    "resolve_effects",
    "effect_names",
    "effects_of_phase",
]

#: Where an effect acts, in pipeline order (see the module docstring for each stage's form).
PHASES = ("shading", "light", "image")
_GAMMA_FLOOR = 1e-8
_TINY = 1e-12


@dataclass(frozen=True)
class EffectSpec:
    """An effect, declared once: its name, phase, parameters, range check and stage.

    ``check(params)`` returns what is wrong with resolved parameters (``None`` when they
    are fine); ``stage(params, declared)`` builds the stage (see the module docstring);
    ``requires`` names effects that must be declared with it.
    """

    name: str
    phase: str  # one of PHASES
    defaults: Mapping[str, Any] = field(default_factory=dict)
    choices: Mapping[str, tuple] = field(default_factory=dict)
    doc: str = ""
    check: Callable[[Mapping[str, Any]], str | None] | None = None
    stage: Callable[[Mapping[str, Any], Mapping[str, Any]], Callable] | None = None
    requires: tuple[str, ...] = ()
    needs_camera: bool = False


class Surface(NamedTuple):
    """What the shading stages read of the surface: unit normal, unit view direction, the
    clamped ``n.v`` and the maps (each ``(..., C, H, W)``)."""

    n: Tensor
    v: Tensor
    cos_v: Tensor  # max(n.v, 0)
    diffuse: Tensor
    roughness: Tensor
    specular: Tensor


class LightPath(NamedTuple):
    """What the per-light stages read of one light: the unit direction to it, the squared
    distance, the clamped ``n.l``, the light's position and point weight ``w``."""

    l: Tensor  # noqa: E741 - the math's name
    d2: Tensor
    cos_l: Tensor  # max(n.l, 0)
    pos: Tensor
    w: Tensor | float  # 1 for a point light, 0 for a directional one


#: The registry, in pipeline order. Tests remove entries to build "a renderer that never
#: heard of" an effect; nothing else mutates it.
EFFECTS: dict[str, EffectSpec] = {}


def _register(name, phase, doc, *, stage=None, check=None, choices=None, requires=(),
              needs_camera=False, **defaults) -> None:
    if phase not in PHASES:  # pragma: no cover - a mistake in this file
        raise ValueError(f"effect {name!r}: phase must be one of {PHASES}, got {phase!r}")
    EFFECTS[name] = EffectSpec(name, phase, dict(defaults), dict(choices or {}), doc, check, stage,
                               tuple(requires), needs_camera)


# -- shading: the BRDF terms ----------------------------------------------------------------


def _diffuse(params, declared):
    def prepare(s: Surface):
        kd = brdf.diffuse_des18(s.diffuse, s.specular)
        return lambda light: kd

    return prepare


def _specular(params, declared):
    fresnel_model = declared["fresnel"]["model"] if "fresnel" in declared else None
    masking_model = declared["masking"]["model"] if "masking" in declared else None
    exact_masking = masking_model in ("smith", "height-correlated")

    def prepare(s: Surface):
        alpha = brdf.alpha_from_roughness(s.roughness, params["alpha_min"], params["alpha_floor"])
        sin2_v = cross_norm_sq(s.n, s.v, -3) if exact_masking else None

        def lobe(light: LightPath) -> Tensor:
            h, _ = unit_and_sq(light.l + s.v)
            out = brdf.ggx_d(dot(s.n, h, -3), cross_norm_sq(s.n, h, -3), alpha) * 0.25
            if masking_model is not None:
                sin2_l = cross_norm_sq(s.n, light.l, -3) if exact_masking else None
                out = out * brdf.visibility(masking_model, light.cos_l, sin2_l, s.cos_v, sin2_v, alpha)
            if fresnel_model is not None:
                return out * brdf.fresnel(fresnel_model, s.specular, dot(s.v, h, -3))
            return out * s.specular

        return lobe

    return prepare


def _check_specular(p):
    if not 0 < p["alpha_min"] < 1:
        return f"alpha_min must be in (0, 1), got {p['alpha_min']}"
    return None


_register("diffuse", "shading", "Lambert term d (1 - s) / pi", stage=_diffuse)
_register(
    "specular",
    "shading",
    "GGX lobe D V F / 4",
    stage=_specular,
    check=_check_specular,
    choices={"alpha_floor": ("remap", "clamp")},
    alpha_min=ALPHA_MIN,
    alpha_floor="remap",
)
_register("fresnel", "shading", "Fresnel factor", choices={"model": FRESNEL_MODELS},
          requires=("specular",), model="des18")
_register("masking", "shading", "shadowing-masking", choices={"model": MASKING_MODELS},
          requires=("specular",), model="schlick-ggx")


# -- light: per-light factors ---------------------------------------------------------------


def _cosine(params, declared):
    return lambda x, s, light: x * light.cos_l


def _falloff(params, declared):
    min_d2 = params["min_distance"] ** 2

    def falloff(x, s: Surface, light: LightPath):
        w = light.w
        if isinstance(w, float) and w == 0.0:  # directional: no distance
            return x
        eff_d2 = light.d2 if isinstance(w, float) else w * light.d2 + (1 - w)
        return x / eff_d2.clamp_min(min_d2)

    return falloff


def _beam(params, declared):
    k = params["exponent"]

    def beam(x, s: Surface, light: LightPath):
        w = light.w
        if isinstance(w, float) and w == 0.0:  # directional: no beam
            return x
        # The light is aimed at the patch centre (the origin): its axis points from the
        # light to the origin, and -l from the light to the pixel. Clamped above 0 so the
        # power's slope stays finite (the clamp passes no gradient there).
        axis, _ = unit_and_sq(light.pos)
        spread = dot(light.l, axis, -3).clamp(_TINY, 1.0).pow(k)
        return x * (spread if isinstance(w, float) else w * spread + (1 - w))

    return beam


def _check_falloff(p):
    return None if p["min_distance"] > 0 else f"min_distance must be > 0, got {p['min_distance']}"


def _check_beam(p):
    return None if 0 <= p["exponent"] <= 1e3 else f"exponent must be in [0, 1000], got {p['exponent']}"


_register("cosine", "light", "max(n.l, 0)", stage=_cosine)
_register("falloff", "light", "inverse-square distance", stage=_falloff, check=_check_falloff,
          min_distance=1e-3)
_register("beam", "light", "flash beam cos^exponent", stage=_beam, check=_check_beam, exponent=2.0)


# -- image: stages on the summed radiance ----------------------------------------------------


def _vignetting(params, declared):
    strength = params["strength"]

    def vignetting(x, geometry, gen):
        # cos of the angle between the camera axis (towards the patch centre) and the
        # ray to each pixel; 1 everywhere for a directional camera.
        v, _ = unit_and_sq(toward(geometry.camera, geometry.camera_w, geometry.positions))
        axis, _ = unit_and_sq(geometry.camera)
        c = dot(v, axis, -3).clamp(0, 1)
        c2 = c * c
        return x * (1 - strength * (1 - c2 * c2))

    return vignetting


def _exposure(params, declared):
    gain = 2.0 ** params["ev"]
    return lambda x, geometry, gen: x * gain


def _noise(params, declared):
    sigma, shot, seed = params["sigma"], params["shot"], params["seed"]

    def noise(x, geometry, gen):
        if gen is None:
            gen = torch.Generator(device=x.device).manual_seed(seed)
        z = torch.randn(x.shape, generator=gen, dtype=x.dtype, device=x.device)
        if shot > 0:  # variance sigma^2 + shot * x, x clamped before the sqrt
            return x + z * torch.sqrt(sigma * sigma + shot * x.clamp_min(0))
        return x + z * sigma

    return noise


def _clip(params, declared):
    top = params["max"]
    return lambda x, geometry, gen: x.clamp(0, top)


def _gamma(params, declared):
    inv = 1.0 / params["gamma"]
    # Clamped before the power: pow(0, 1/2.2) has an infinite slope.
    return lambda x, geometry, gen: x.clamp_min(_GAMMA_FLOOR).pow(inv)


def _tone(params, declared):
    power, shoulder = params["power"], params["shoulder"]

    def tone(x, geometry, gen):
        # Clamped at a floor first: a power below 1 has an infinite slope at 0.
        y = x.clamp_min(_GAMMA_FLOOR)
        if power != 1.0:
            y = y.pow(power)
        if shoulder > 0:
            y = y * (1 + shoulder) / (1 + shoulder * y)
        return y

    return tone


def _check_tone(p):
    if not 0.25 <= p["power"] <= 4:
        return f"power must be in [0.25, 4], got {p['power']}"
    if not 0 <= p["shoulder"] <= 20:
        return f"shoulder must be in [0, 20], got {p['shoulder']}"
    return None


def _positive(key: str):
    return lambda p: None if p[key] > 0 else f"{key} must be > 0, got {p[key]}"


def _check_vignetting(p):
    return None if 0 <= p["strength"] <= 1 else f"strength must be in [0, 1], got {p['strength']}"


def _check_noise(p):
    return None if p["sigma"] >= 0 and p["shot"] >= 0 else "sigma and shot must be >= 0"


_register("vignetting", "image", "cos^4 lens falloff", stage=_vignetting, check=_check_vignetting,
          needs_camera=True, strength=1.0)
_register("exposure", "image", "gain 2**ev", stage=_exposure, ev=0.0)
_register("noise", "image", "seeded sensor noise", stage=_noise, check=_check_noise,
          sigma=0.01, shot=0.0, seed=0)
_register("clip", "image", "saturation to [0, max]", stage=_clip, check=_positive("max"), max=1.0)
_register("tone", "image", "tone curve x**power with a highlight shoulder", stage=_tone,
          check=_check_tone, power=1.0, shoulder=0.0)
_register("gamma", "image", "display encoding x**(1/gamma)", stage=_gamma, check=_positive("gamma"),
          gamma=2.2)

#: The Deschaintre 2018 rendering: what reproduces the Des18 data set inputs. The one
#: spelling of this set; the renderer and its hand-derived backward import it.
DES18_EFFECTS = ("diffuse", "specular", "fresnel", "masking", "cosine", "falloff")
#: A simulated phone photo: Des18 shading plus exposure, noise and clipping. The one spelling
#: of the photo the data generator makes (``svbrdf_train.data.simulated_photo.photo_scene`` declares
#: these, with drawn parameters, and gamma for a share of the photos): no vignetting, which the
#: training photos never had.
PHOTO_EFFECTS = DES18_EFFECTS + ("exposure", "noise", "clip")


def effect_names() -> tuple[str, ...]:
    return tuple(EFFECTS)


def effects_of_phase(declared: Mapping[str, Any], *phases: str) -> dict[str, Any]:
    """The entries of a resolved declaration whose effects act in one of ``phases``."""
    return {name: params for name, params in declared.items() if EFFECTS[name].phase in phases}


# -- resolving a declaration -----------------------------------------------------------------


def _unknown(what: str, name: str, known) -> SceneError:
    close = difflib.get_close_matches(name, list(known), n=3)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return SceneError(f"unknown {what} {name!r}{hint} Known: {', '.join(known)}")


def _items(effects) -> list[tuple[str, Any]]:
    """A declaration as ``(name, params)`` pairs: a mapping, or a list of names and
    one-key mappings."""
    if isinstance(effects, str):
        raise SceneError(
            f"effects: expected a list of names or a mapping, got the string {effects!r}"
        )
    if isinstance(effects, Mapping):
        return list(effects.items())
    items = []
    for e in effects:
        if isinstance(e, str):
            items.append((e, None))
        elif isinstance(e, Mapping) and len(e) == 1:
            items.extend(e.items())
        else:
            raise SceneError(f"effects: expected a name or a one-key mapping, got {e!r}")
    return items


def _typed(spec: EffectSpec, key: str, value: Any) -> Any:
    """``value`` checked against the type (or choices) of the parameter's default."""
    name, default = spec.name, spec.defaults[key]
    if key in spec.choices:
        if value not in spec.choices[key]:
            raise SceneError(f"effect {name!r}: {key} must be one of {spec.choices[key]}, got {value!r}")
    elif isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"effect {name!r}: {key} must be an integer, got {value!r}")
    elif isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"effect {name!r}: {key} must be a number, got {value!r}")
        value = float(value)
    return value


def _resolve_params(spec: EffectSpec, params) -> dict[str, Any]:
    """One effect's parameters with defaults filled in, typed and range-checked."""
    if params is None or params is True:
        params = {}
    if not isinstance(params, Mapping):
        raise SceneError(f"effect {spec.name!r}: expected a mapping of parameters, got {params!r}")
    resolved = dict(spec.defaults)
    for key, value in params.items():
        if key not in spec.defaults:
            if spec.defaults:
                raise _unknown(f"parameter of effect {spec.name!r}:", key, spec.defaults)
            raise SceneError(f"effect {spec.name!r} takes no parameters, got {key!r}")
        resolved[key] = _typed(spec, key, value)
    problem = spec.check(resolved) if spec.check is not None else None
    if problem is not None:
        raise SceneError(f"effect {spec.name!r}: {problem}")
    return resolved


def resolve_effects(effects) -> dict[str, dict[str, Any]]:
    """Normalise a declaration to ``{name: {param: value}}`` with defaults filled in.

    Accepts a list of names, a mapping ``name -> params`` (``None``/``{}``/``True`` for
    defaults, ``False`` to leave it out), or a mix. The result is ordered as the pipeline
    runs.
    """
    if effects is None:
        return {}
    declared: dict[str, dict[str, Any]] = {}
    for name, params in _items(effects):
        if name not in EFFECTS:
            raise _unknown("effect", name, EFFECTS)
        if params is not False:
            declared[name] = _resolve_params(EFFECTS[name], params)
    for name in declared:
        for needed in EFFECTS[name].requires:
            if needed not in declared:
                raise SceneError(
                    f"effects: {name!r} modifies the {needed!r} effect; declare {needed!r} too"
                )
    return {name: declared[name] for name in EFFECTS if name in declared}
