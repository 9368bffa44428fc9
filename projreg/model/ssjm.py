"""SSJM: Saliency-Statistics Joint Modulation of a feature map (our reading of the paper's section 3.2.2).

The paper gives the idea in words and a formula whose symbols did not survive extraction; DESIGN.md
section 9 fixes our reading:

* saliency energy branch (no weights): a pixel's energy is its squared distance to the channel's
  spatial mean, normalised by the channel's spatial variance,
  ``E = (X - mu)^2 / (4 (sigma^2 + lambda)) + 0.5`` and ``Xs = X * sigmoid(E)``;
* statistical spatial attention branch: ``M = sigmoid(conv7x7([max_c(Xs); mean_c(Xs)]))`` and the
  output is ``Y = Xs * M``.

The statistics are per sample and per channel, so running both images of a pair through one call
(concatenated along the batch) is the same as two calls with shared weights.
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import ProjregError


def saliency_energy(x: torch.Tensor, lam: float) -> torch.Tensor:
    """Per-pixel saliency energy ``E = (X - mu)^2 / (4 (sigma^2 + lambda)) + 0.5``.

    Args:
        x: feature map.
        lam: the small constant lambda added to the variance.

    Returns:
        E, same shape as ``x``.

    Convention: ``x`` is ``[B, C, H, W]``; mu and sigma^2 are the spatial mean and population variance
    of each channel of each sample.
    """
    mu = x.mean(dim=(2, 3), keepdim=True)  # [B, C, 1, 1]
    d2 = (x - mu).square()  # [B, C, H, W]
    var = d2.mean(dim=(2, 3), keepdim=True)  # [B, C, 1, 1]
    return d2 / (4.0 * (var + lam)) + 0.5


class SSJM(nn.Module):
    """Saliency-Statistics Joint Modulation (our reading of the paper's section 3.2.2).

    ``Xs = X * sigmoid(E)`` with the saliency energy ``E`` of :func:`saliency_energy`, then
    ``Y = Xs * sigmoid(conv7x7([max_c(Xs); mean_c(Xs)]))``; the 7x7 convolution maps the two pooled
    maps to one gating mask (padding 3, with bias). About 100 parameters.

    Args:
        lam: lambda, the small constant added to the channel variance (> 0).

    Convention: input and output are ``[B, C, H, W]``; apply to the projected and the captured
    feature maps with the same module (shared weights).
    """

    def __init__(self, lam: float = 1e-4) -> None:
        super().__init__()
        if not lam > 0:
            raise ProjregError(f"SSJM lambda must be > 0, got {lam}")
        self.lam = float(lam)
        self.conv = nn.Conv2d(2, 1, kernel_size=7, padding=3, bias=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        xs = x * torch.sigmoid(saliency_energy(x, self.lam))  # [B, C, H, W]
        pooled = torch.cat([xs.amax(dim=1, keepdim=True), xs.mean(dim=1, keepdim=True)], dim=1)  # [B, 2, H, W]
        mask = torch.sigmoid(self.conv(pooled))  # [B, 1, H, W]
        return xs * mask

    def extra_repr(self) -> str:
        return f"lam={self.lam:g}"
