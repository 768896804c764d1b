"""Weight initialisation shared by the built-in networks."""

from __future__ import annotations

from torch import nn

__all__ = ["normal_init"]


def normal_init(module: nn.Module, std: float) -> None:
    """pix2pix's init for every conv, deconv and linear layer inside ``module``: weights
    ~ N(0, std), biases 0. Other layers (norms, attention plugins' own) are left alone."""

    def visit(m: nn.Module) -> None:
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, std)
            if m.bias is not None:
                nn.init.zeros_(m.bias)

    module.apply(visit)
