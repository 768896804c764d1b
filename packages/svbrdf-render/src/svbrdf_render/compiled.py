"""The compiled backend: the shading stage through ``torch.compile``, and what that takes.

``render(..., backend="compiled")`` shades through :func:`shade_compiled`: the plan's shading
stage compiled once per shading configuration (one fused kernel per shape; the first call
compiles), with the hand-derived backward of :mod:`svbrdf_render.fused` for the Des18 shading
when only the maps need gradients. Here too: the cache of compiled functions (:data:`_COMPILED`,
one code object per function so that Dynamo's per-code cache limit is not shared), and the
fallback to the eager stage, with one warning, on a platform that cannot compile.
"""

from __future__ import annotations

import types
import warnings
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from . import fused
from .effects import effects_of_phase
from .stages import SceneGeometry, ShadeStage

__all__ = ["shade_compiled"]

#: The compiled functions (or their eager fallbacks), by what they compute.
_COMPILED: dict[str, Callable[..., Any]] = {}


def _is_compile_failure(exc: Exception) -> bool:
    """True for a failure of the compiler itself (no C++ toolchain, Inductor), not the inputs."""
    try:
        from torch._dynamo.exc import BackendCompilerFailed
    except ImportError:  # pragma: no cover - torch without dynamo
        return False
    return isinstance(exc, BackendCompilerFailed)


def _reason(exc: Exception) -> str:
    """One line naming why compiling failed (the backend's own exception where it has one)."""
    inner = getattr(exc, "inner_exception", None)
    exc = inner if isinstance(inner, Exception) else exc
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    name = type(exc).__name__
    if not lines:
        return name
    return lines[0] if lines[0].startswith(name) else f"{name}: {lines[0]}"


def _own_code(fn: Callable[..., Tensor]) -> Callable[..., Tensor]:
    """``fn`` with a code object of its own (same bytecode, closure and globals).

    Dynamo keeps compiled graphs, and counts them against ``recompile_limit`` (8), per
    *code object*. Every plan's ``shade`` is the same nested function with other closure
    values, so without this all plans would share one cache of 8 entries: from the ninth
    plan/shape/dtype/grad-mode combination in a process on, Dynamo would stop compiling
    and the "compiled" backend would silently run eager.
    """
    own = types.FunctionType(
        fn.__code__.replace(), fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__
    )
    own.__kwdefaults__ = fn.__kwdefaults__
    own.__qualname__ = fn.__qualname__
    return own


def _compile_with_fallback(key: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` through ``torch.compile``, cached under ``key``, falling back to ``fn``.

    ``torch.compile`` compiles lazily, so a platform that cannot compile (no C++ compiler,
    unsupported Python) fails at the first *call*; that call, and every later one under
    ``key``, then runs ``fn`` eagerly, with one warning. Compilation is static in shape
    (``dynamic=False``): new tensors of a seen shape reuse the compiled kernels; a new shape
    (or dtype, grad mode, point/directional mix) compiles once more, up to Dynamo's
    ``recompile_limit`` per function (see :func:`_own_code`).
    """
    cached = _COMPILED.get(key)
    if cached is not None:
        return cached
    try:
        compiled = torch.compile(_own_code(fn), dynamic=False)
    except Exception as e:  # pragma: no cover - platform without torch.compile
        warnings.warn(f"torch.compile unavailable ({e}); using the eager backend", stacklevel=3)
        _COMPILED[key] = fn
        return fn

    def run(*args: Any) -> Any:
        try:
            return compiled(*args)
        except Exception as e:
            if not _is_compile_failure(e):
                raise
            warnings.warn(f"torch.compile failed ({_reason(e)}); using the eager backend", stacklevel=3)
            _COMPILED[key] = fn
            return fn(*args)

    _COMPILED[key] = run
    return run


def _shade_key(effects: dict[str, dict[str, Any]]) -> str:
    # What ``shade`` depends on: plans that differ only in image effects share it.
    shading = effects_of_phase(effects, "shading", "light")
    return repr([(k, sorted(v.items())) for k, v in shading.items()])


def _compiled_des18_backward(effects: dict[str, dict[str, Any]]) -> Callable[..., tuple[Tensor, ...]]:
    """The hand-derived backward of :mod:`svbrdf_render.fused`, compiled for these effects."""

    def backward(grad, normal, diffuse, roughness, specular, geometry):
        return fused.des18_shading_grads(effects, grad, normal, diffuse, roughness, specular, geometry)

    return _compile_with_fallback("des18-backward" + _shade_key(effects), backward)


class _FusedShade(torch.autograd.Function):
    """Compiled shading whose backward recomputes instead of saving intermediates."""

    @staticmethod
    def forward(ctx, normal, diffuse, roughness, specular, geometry, forward_fn, backward_fn):
        ctx.save_for_backward(normal, diffuse, roughness, specular)
        ctx.extra = (geometry, backward_fn)
        return forward_fn(normal, diffuse, roughness, specular, geometry)

    @staticmethod
    def backward(ctx, grad):
        normal, diffuse, roughness, specular = ctx.saved_tensors
        geometry, backward_fn = ctx.extra
        grads = backward_fn(grad.contiguous(), normal, diffuse, roughness, specular, geometry)
        return (*grads, None, None, None)


def shade_compiled(
    effects: dict[str, dict[str, Any]], shade: ShadeStage, maps: list[Tensor], geometry: SceneGeometry
) -> Tensor:
    """The shading stage ``shade`` of a plan declaring ``effects``, run compiled (cached per
    shading configuration): the hand-derived backward for the Des18 shading when only the maps
    need gradients, autograd through the compiled stage otherwise."""
    forward_fn = _compile_with_fallback("shade" + _shade_key(effects), shade)
    if (
        fused.supports(effects)
        and torch.is_grad_enabled()
        and any(m.requires_grad for m in maps)
        and not geometry.requires_grad()
    ):
        return _FusedShade.apply(*maps, geometry, forward_fn, _compiled_des18_backward(effects))
    return forward_fn(*maps, geometry)
