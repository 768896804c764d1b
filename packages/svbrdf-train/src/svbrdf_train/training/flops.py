"""The model FLOPs of a training step, and how far a measured throughput is from the hardware's peak.

:func:`step_flops` counts, with ``torch.utils.flop_counter``, the floating-point operations
of the convolutions, matrix products and attention of one real training step (generator
forward and backward, discriminator steps averaged over their ``g_steps_per_d`` cycle), per
sample. Element-wise work (the renderer, the losses, Adam) is not counted: these are "model
FLOPs" as in model FLOP utilisation (MFU), the share of the peak a step turns into network
arithmetic.

:func:`peak_tflops` gives the dense peak of the device for the step's precision: on NVIDIA
GPUs from the data-sheet table :data:`GPU_PEAK_TFLOPS` (float32 steps count against the TF32
peak, since cuDNN runs float32 convolutions on TF32 tensor cores by default in PyTorch); on a
CPU the rate of a large float32 matrix product measured on the spot, the most this CPU gets
from PyTorch.
"""

from __future__ import annotations

import time
from dataclasses import replace

import torch

from ..recipe import Recipe

__all__ = ["GPU_PEAK_TFLOPS", "count_flops", "step_flops", "peak_tflops"]

#: Dense peak TFLOP/s from NVIDIA's data sheets: name substring -> (tf32, bf16).
GPU_PEAK_TFLOPS: dict[str, tuple[float, float]] = {
    "H200": (494.7, 989.4),
    "H100 PCIe": (378.0, 756.0),
    "H100": (494.7, 989.4),  # SXM5 (HBM3); checked after "H100 PCIe"
    "A100": (156.0, 312.0),
    "L40S": (183.0, 362.0),
    "A10": (62.5, 125.0),
}


def count_flops(fn) -> int:
    """FLOPs ``torch.utils.flop_counter`` counts while ``fn()`` runs: convolutions, matrix
    products and attention, a multiply-add as 2; element-wise ops, norms and pooling count 0."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


def step_flops(recipe: Recipe, device: str | torch.device = "cpu") -> dict[str, float]:
    """Model FLOPs per sample of ``recipe``'s training step on ``device`` (module doc).

    Returns ``{"generator_forward", "step"}``: one generator forward, and one whole step
    (G forward and backward, and D's share of its steps), per sample. The step's networks are
    made afresh and stepped on procedural samples; nothing else is touched.
    """
    from ..data import ProceduralMaterials
    from . import distributed
    from .step import GanStep

    device = torch.device(device)
    t = recipe.train
    # the eager renderer: the counter does not see inside compiled code, and renders count nothing
    recipe = replace(recipe, train=replace(t, render_backend="eager", compile=False))
    gan = GanStep(recipe, distributed.Dist(device=device), epoch_samples=10**9)
    gan.prepare()
    batch = ProceduralMaterials(t.batch, t.resolution, seed=1).batch(list(range(t.batch)))
    photo = batch["input"].to(device)
    with torch.no_grad():
        forward = count_flops(lambda: gan.generator(photo))
    every = recipe.optim.g_steps_per_d if gan.discriminator is not None else 1
    with_d = count_flops(lambda: gan(batch))  # step 0: the discriminator steps too
    without_d = count_flops(lambda: gan(batch)) if every > 1 else with_d
    per_step = (with_d + (every - 1) * without_d) / every
    return {"generator_forward": forward / t.batch, "step": per_step / t.batch}


def peak_tflops(device: str | torch.device, precision: str = "fp32") -> tuple[float | None, str]:
    """The dense peak TFLOP/s of ``device`` at ``precision`` (fp32 or bf16) and where it comes
    from; ``(None, why)`` for a GPU not in :data:`GPU_PEAK_TFLOPS`."""
    device = torch.device(device)
    if device.type == "cuda":
        name = torch.cuda.get_device_name(device)
        for key, (tf32, bf16) in GPU_PEAK_TFLOPS.items():
            if key in name:
                kind = "BF16" if precision == "bf16" else "TF32"
                return (bf16 if precision == "bf16" else tf32), f"{name}, dense {kind} data-sheet peak"
        return None, f"{name}: no data-sheet peak known (svbrdf_train.training.flops.GPU_PEAK_TFLOPS)"
    return _measured_cpu_peak(), f"a 2048x2048 float32 matmul on {torch.get_num_threads()} thread(s)"


def _measured_cpu_peak(size: int = 2048, seconds: float = 0.5) -> float:
    a, b = torch.randn(size, size), torch.randn(size, size)
    a @ b  # warm-up
    runs, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        a @ b
        runs += 1
    return 2 * size**3 * runs / (time.perf_counter() - start) / 1e12
