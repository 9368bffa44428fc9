"""CNN feature encoder: an image to features at 1/8 (and optionally 1/4) of its resolution.

A small ResNet with instance normalisation: a stride-2 7x7 stem, three stages of two residual blocks
(strides 1, 2, 2), then a 1x1 projection to ``feature_channels``. Instance norm keeps the features of
the projected and the captured image comparable whatever their brightness and contrast, which differ a
lot between a frame buffer and a camera frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import ProjregError


class ResidualBlock(nn.Module):
    """Two 3x3 convolutions with instance norm and ReLU, plus a (projected) shortcut.

    Convention: ``[B, in_channels, H, W]`` -> ``[B, out_channels, ceil(H / stride), ceil(W / stride)]``.
    """

    def __init__(self, in_channels: int, out_channels: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, out_channels, kernel_size=3, stride=stride, padding=1)
        self.conv2 = nn.Conv2d(out_channels, out_channels, kernel_size=3, padding=1)
        self.norm1 = nn.InstanceNorm2d(out_channels)
        self.norm2 = nn.InstanceNorm2d(out_channels)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_channels != out_channels:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, kernel_size=1, stride=stride),
                nn.InstanceNorm2d(out_channels),
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # in place is safe: instance norm's backward needs its input, not its output
        y = F.relu(self.norm1(self.conv1(x)), inplace=True)
        y = F.relu(self.norm2(self.conv2(y)), inplace=True)
        return F.relu(self.shortcut(x) + y, inplace=True)


class CNNEncoder(nn.Module):
    """ResNet-like encoder to 1/8 resolution, optionally with a 1/4-resolution feature for refinement.

    Args:
        stage_channels: channels of the three stages (at 1/2, 1/4 and 1/8 resolution); the stem has
            ``stage_channels[0]``.
        feature_channels: channels of the returned features.
        with_quarter: also return a 1/4-resolution feature: the 1/4 stage output fused with the
            upsampled 1/8 feature (top-down, as a feature pyramid), so it carries the coarse context.

    Convention: input ``[B, 3, H, W]`` normalised image with ``H``, ``W`` multiples of 8; returns
    ``(f8, f4)``: f8 ``[B, feature_channels, H/8, W/8]``, f4 ``[B, feature_channels, H/4, W/4]`` or
    None when ``with_quarter`` is false.
    """

    def __init__(self, stage_channels: Sequence[int], feature_channels: int, with_quarter: bool) -> None:
        super().__init__()
        if len(stage_channels) != 3 or min(stage_channels) < 1:
            raise ProjregError(f"stage_channels must be 3 positive ints, got {list(stage_channels)}")
        c1, c2, c3 = (int(c) for c in stage_channels)
        self.stem = nn.Sequential(
            nn.Conv2d(3, c1, kernel_size=7, stride=2, padding=3),
            nn.InstanceNorm2d(c1),
            nn.ReLU(inplace=True),
        )
        self.stage1 = nn.Sequential(ResidualBlock(c1, c1, stride=1), ResidualBlock(c1, c1, stride=1))
        self.stage2 = nn.Sequential(ResidualBlock(c1, c2, stride=2), ResidualBlock(c2, c2, stride=1))
        self.stage3 = nn.Sequential(ResidualBlock(c2, c3, stride=2), ResidualBlock(c3, c3, stride=1))
        self.out8 = nn.Conv2d(c3, feature_channels, kernel_size=1)
        self.out4 = nn.Conv2d(c2 + feature_channels, feature_channels, kernel_size=1) if with_quarter else None

    def forward(self, img: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        x = self.stage1(self.stem(img))  # [B, c1, H/2, W/2]
        x4 = self.stage2(x)  # [B, c2, H/4, W/4]
        f8 = self.out8(self.stage3(x4))  # [B, C, H/8, W/8]
        if self.out4 is None:
            return f8, None
        up = F.interpolate(f8, size=x4.shape[-2:], mode="bilinear", align_corners=False)  # [B, C, H/4, W/4]
        f4 = self.out4(torch.cat([x4, up], dim=1))  # [B, C, H/4, W/4]
        return f8, f4
