"""Flow propagation by self-attention: each pixel takes the flow of the pixels whose feature it shares.

Global matching is unreliable where img0 has no distinctive feature, is occluded or leaves the camera
frame; propagation replaces the flow there by a feature-similarity-weighted average of the flow
elsewhere in img0 (globally at 1/8, in a small window at 1/4).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .matching import local_window_gather, local_window_scores, window_softmax


class FlowPropagation(nn.Module):
    """``flow'(p) = sum_q softmax_q(<Wq f(p), Wk f(q)> / sqrt(C)) flow(q)`` over img0 pixels q.

    ``Wq`` and ``Wk`` start as the identity, so an untrained module averages over pixels with similar
    features.

    Args:
        channels: feature channels C.
        radius: None for global attention over all pixels; r >= 1 for a ``(2r+1)^2`` window.

    Convention: ``forward(feature [B, C, H, W], flow [B, 2, H, W]) -> [B, 2, H, W]``; the feature is
    img0's (projected) and the flow img0 -> img1 in pixels of this map.
    """

    def __init__(self, channels: int, radius: int | None) -> None:
        super().__init__()
        self.radius = radius
        self.q = nn.Linear(channels, channels)
        self.k = nn.Linear(channels, channels)
        for lin in (self.q, self.k):
            nn.init.eye_(lin.weight)
            nn.init.zeros_(lin.bias)

    def forward(self, feature: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        b, c, h, w = feature.shape
        x = feature.flatten(2).transpose(1, 2)  # [B, H*W, C]
        q, k = self.q(x), self.k(x)  # [B, H*W, C]
        if self.radius is None:
            prob = torch.softmax(torch.bmm(q / math.sqrt(c), k.transpose(1, 2)), dim=-1)  # [B, H*W, H*W]
            out = torch.bmm(prob, flow.flatten(2).transpose(1, 2))  # [B, H*W, 2]
            return out.transpose(1, 2).reshape(b, 2, h, w)
        qm = q.transpose(1, 2).reshape(b, c, h, w)  # [B, C, H, W]
        km = k.transpose(1, 2).reshape(b, c, h, w)  # [B, C, H, W]
        prob = window_softmax(local_window_scores(qm, km, self.radius))  # [B, K, H, W]
        return local_window_gather(flow, prob, self.radius)

    def extra_repr(self) -> str:
        return f"radius={self.radius}"
