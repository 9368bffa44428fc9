"""SSJMFlow: the registration network, and its named configurations.

backbone (1/8, optionally 1/4) -> SSJM -> feature transformer -> global correlation softmax (1/8)
-> flow propagation -> [refinement at 1/4: warp, local correlation softmax, local propagation]
-> convex upsampling to full resolution.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from ..errors import ProjregError
from .backbone import CNNEncoder
from .matching import (
    ConvexUpsampler,
    bilinear_upsample_flow,
    flow_warp,
    global_correlation_softmax,
    local_correlation_softmax,
)
from .propagation import FlowPropagation
from .ssjm import SSJM
from .transformer import FeatureTransformer

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

MODEL_CONFIGS: dict[str, dict[str, Any]] = {
    # trains on a 2-core CPU; ships in the repository
    "small": {
        "feature_channels": 96,
        "backbone_channels": [32, 64, 96],
        "num_transformer_layers": 3,
        "ffn_dim_expansion": 2,
        "attn_splits": 2,
        "refine": True,
        "refine_radius": 4,
        "upsampler_channels": 64,
    },
    # GMFlow-sized (one scale, about 4.7 M parameters)
    "base": {
        "feature_channels": 128,
        "backbone_channels": [64, 96, 128],
        "num_transformer_layers": 6,
        "ffn_dim_expansion": 4,
        "attn_splits": 2,
        "refine": False,
        "refine_radius": 4,
        "upsampler_channels": 256,
    },
}

# Bounds on a checkpoint's ``model_config`` (SSJMFlow's arguments), checked before a model is built: well
# above both configurations, low enough that a file from elsewhere cannot make building the model
# allocate without limit (``attn_splits`` 10**6 asked predict for 1.5 PB, ``feature_channels`` 65536 17 GB).
CONFIG_BOUNDS: dict[str, tuple[float, float]] = {
    "feature_channels": (4, 512),
    "backbone_channels": (1, 512),
    "num_transformer_layers": (0, 12),
    "ffn_dim_expansion": (1, 8),
    "attn_splits": (1, 8),
    "ssjm_lambda": (1e-12, 1.0),
    "refine_radius": (1, 8),
    "upsampler_channels": (1, 512),
}
CONFIG_FLAGS = ("use_ssjm", "refine")


def checked_config(config: object) -> dict[str, Any]:
    """``config`` when it holds only SSJMFlow arguments within ``CONFIG_BOUNDS`` (integers, but for
    ``ssjm_lambda``; ``backbone_channels`` three of them) and booleans for ``CONFIG_FLAGS``.

    Raises:
        ProjregError: naming the first field that is unknown, of the wrong type or out of bounds.
    """
    if not isinstance(config, dict):
        raise ProjregError(f"model_config is a {type(config).__name__}, expected a dict of SSJMFlow arguments")
    for key, value in config.items():
        if key in CONFIG_FLAGS:
            if not isinstance(value, bool):
                raise ProjregError(f"model_config {key} is {value!r:.40}, expected true or false")
            continue
        if key not in CONFIG_BOUNDS:
            raise ProjregError(f"model_config {key!s:.40} is not an argument of SSJMFlow")
        lo, hi = CONFIG_BOUNDS[key]
        triple = key == "backbone_channels"
        values = value if triple and isinstance(value, list | tuple) and len(value) == 3 else [value]
        if triple and len(values) != 3 or not all(_number_within(key, v, lo, hi) for v in values):
            what = "three integers" if triple else "a number" if key == "ssjm_lambda" else "an integer"
            raise ProjregError(f"model_config {key} is {value!r:.40}, expected {what} in {lo:g}..{hi:g}")
    return config


def _number_within(key: str, v: object, lo: float, hi: float) -> bool:
    kinds = (int, float) if key == "ssjm_lambda" else int
    return isinstance(v, kinds) and not isinstance(v, bool) and lo <= v <= hi  # NaN fails the comparison


class SSJMFlow(nn.Module):
    """Global-matching optical flow with Saliency-Statistics Joint Modulation of the features.

    Args:
        feature_channels: channels C of the matching features (multiple of 4).
        backbone_channels: channels of the encoder's three stages (1/2, 1/4, 1/8).
        num_transformer_layers: (self, cross) attention layer pairs.
        ffn_dim_expansion: FFN expansion of the cross-attention layers.
        attn_splits: attention windows per side at 1/8.
        use_ssjm: apply SSJM to the 1/8 features of both images (False: the paper's ablation).
        ssjm_lambda: SSJM's lambda.
        refine: refine at 1/4 with local correlation (radius ``refine_radius``) and local propagation.
        refine_radius: local-correlation radius at 1/4, in 1/4-resolution pixels.
        upsampler_channels: hidden width of the convex upsampler.

    ``model.config`` holds these arguments, so ``SSJMFlow(**model.config)`` rebuilds the model.

    Convention: ``forward(img0, img1)`` with img0 the projected and img1 the captured image, both
    ``[B, 3, H, W]`` float RGB in [0, 255], any ``H x W`` (replicate-padded at the bottom and right
    to a multiple of ``8 * attn_splits``, outputs cropped back); returns the flow predictions, each
    ``[B, 2, H, W]`` forward projected -> captured in pixels (channel 0 = u to the right, 1 = v down):
    ``[global match, propagated]`` (1/8, bilinear / convex upsampled), and with ``refine``
    ``[global match, propagated, local match at 1/4, propagated at 1/4 (convex)]``. The last one is
    the answer.
    """

    def __init__(
        self,
        *,
        feature_channels: int = 128,
        backbone_channels: Sequence[int] = (64, 96, 128),
        num_transformer_layers: int = 6,
        ffn_dim_expansion: int = 4,
        attn_splits: int = 2,
        use_ssjm: bool = True,
        ssjm_lambda: float = 1e-4,
        refine: bool = False,
        refine_radius: int = 4,
        upsampler_channels: int = 256,
    ) -> None:
        super().__init__()
        if feature_channels < 4 or feature_channels % 4:
            raise ProjregError(f"feature_channels must be a positive multiple of 4, got {feature_channels}")
        if attn_splits < 1 or num_transformer_layers < 0 or ffn_dim_expansion < 1 or refine_radius < 1:
            raise ProjregError(
                "need attn_splits >= 1, num_transformer_layers >= 0, ffn_dim_expansion >= 1, refine_radius >= 1"
            )
        self.config: dict[str, Any] = {
            "feature_channels": int(feature_channels),
            "backbone_channels": [int(c) for c in backbone_channels],
            "num_transformer_layers": int(num_transformer_layers),
            "ffn_dim_expansion": int(ffn_dim_expansion),
            "attn_splits": int(attn_splits),
            "use_ssjm": bool(use_ssjm),
            "ssjm_lambda": float(ssjm_lambda),
            "refine": bool(refine),
            "refine_radius": int(refine_radius),
            "upsampler_channels": int(upsampler_channels),
        }
        c = feature_channels
        self.refine = refine
        self.refine_radius = refine_radius
        # the 1/8 map must split into attn_splits windows per side
        self.pad_multiple = 8 * attn_splits
        self.register_buffer("mean", 255.0 * torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", 255.0 * torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

        self.backbone = CNNEncoder(backbone_channels, c, with_quarter=refine)
        self.ssjm = SSJM(ssjm_lambda) if use_ssjm else None
        self.transformer = FeatureTransformer(c, num_transformer_layers, ffn_dim_expansion, attn_splits)
        self.propagate8 = FlowPropagation(c, radius=None)
        self.propagate4 = FlowPropagation(c, radius=1) if refine else None
        self.upsampler = ConvexUpsampler(c, upsampler_channels, factor=4 if refine else 8)

    @property
    def feature_dtype(self) -> torch.dtype:
        """dtype of the feature stages: float32 unless :meth:`cast_features` changed it."""
        return self.backbone.stem[0].weight.dtype

    def cast_features(self, dtype: torch.dtype) -> SSJMFlow:
        """Run the feature stages (backbone, SSJM, transformer) in ``dtype``, weights included.

        Matching, propagation, the 1/4 refinement and upsampling keep float32 weights and run in
        float32 whatever ``dtype`` is (as under autocast): correlation softmaxes and their expected
        positions are sub-pixel coordinates, which bfloat16 rounds to 1/2 px at 128 px. Returns self.
        """
        for stage in (self.backbone, self.ssjm, self.transformer):
            if stage is not None:
                stage.to(dtype)
        return self

    def forward(self, img0: torch.Tensor, img1: torch.Tensor) -> list[torch.Tensor]:
        if img0.dim() != 4 or img0.shape[1] != 3 or img0.shape != img1.shape:
            raise ProjregError(
                f"expected two [B, 3, H, W] images of one shape, got {tuple(img0.shape)} and {tuple(img1.shape)}"
            )
        b, _, h, w = img0.shape
        m = self.pad_multiple
        x = (torch.cat([img0, img1], dim=0).float() - self.mean) / self.std  # [2B, 3, H, W]
        x = pad_replicate(x, m).to(self.feature_dtype)  # [2B, 3, H', W']

        f8, f4 = self.backbone(x)  # [2B, C, H'/8, W'/8], [2B, C, H'/4, W'/4] or None
        if self.ssjm is not None:
            f8 = self.ssjm(f8)  # both images in one batch: shared weights, per-image statistics
        f0, f1 = self.transformer(f8[:b], f8[b:])  # [B, C, H'/8, W'/8] each

        # flow arithmetic in float32 even under autocast: half precision cannot hold sub-pixel
        # coordinates (its step is 1/16 px at 64 px)
        with torch.autocast(device_type=x.device.type, enabled=False):
            f0, f1 = _at_least_float32(f0), _at_least_float32(f1)
            flow, _ = global_correlation_softmax(f0, f1)  # [B, 2, H'/8, W'/8]
            preds = [bilinear_upsample_flow(flow, 8)]
            flow = self.propagate8(f0, flow)  # [B, 2, H'/8, W'/8]
            if self.refine:
                preds.append(bilinear_upsample_flow(flow, 8))
                preds += self._refine4(_at_least_float32(f4[:b]), _at_least_float32(f4[b:]), flow)
            else:
                preds.append(self.upsampler(flow, f0))
        return [p[:, :, :h, :w] for p in preds]

    def _refine4(self, f0: torch.Tensor, f1: torch.Tensor, flow8: torch.Tensor) -> list[torch.Tensor]:
        """Refinement at 1/4 of the propagated 1/8 flow: ``[local match, propagated]`` at full resolution.

        f0, f1 are the 1/4 features ``[B, C, H'/4, W'/4]``, flow8 ``[B, 2, H'/8, W'/8]``.
        """
        # the refinement learns a residual on top of a fixed coarse flow (as RAFT / GMFlow)
        flow = bilinear_upsample_flow(flow8.detach(), 2)  # [B, 2, H'/4, W'/4]
        residual, _ = local_correlation_softmax(f0, flow_warp(f1, flow), self.refine_radius)
        flow = flow + residual  # [B, 2, H'/4, W'/4]
        preds = [bilinear_upsample_flow(flow, 4)]
        flow = self.propagate4(f0, flow)  # [B, 2, H'/4, W'/4]
        preds.append(self.upsampler(flow, f0))
        return preds


def pad_replicate(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """``[B, C, H, W]`` replicate-padded at the bottom and right to multiples of ``multiple``.

    An index gather rather than ``F.pad``: the padded size ``multiple * ceil(H / multiple)`` is then
    visibly a multiple, so an exported graph (``projreg.onnx``) pads any height and width itself.
    """
    h, w = x.shape[-2:]
    rows = torch.arange((h + multiple - 1) // multiple * multiple, device=x.device).clamp(max=h - 1)  # [H']
    cols = torch.arange((w + multiple - 1) // multiple * multiple, device=x.device).clamp(max=w - 1)  # [W']
    return x.index_select(2, rows).index_select(3, cols)


def _at_least_float32(x: torch.Tensor) -> torch.Tensor:
    return x.to(torch.promote_types(x.dtype, torch.float32))


def build_model(name: str, use_ssjm: bool = True) -> SSJMFlow:
    """Build a named configuration from :data:`MODEL_CONFIGS` (``"small"`` or ``"base"``).

    Args:
        name: configuration name.
        use_ssjm: False builds the paper's "without SSJM" ablation.

    Returns:
        A freshly initialised :class:`SSJMFlow`.
    """
    if name not in MODEL_CONFIGS:
        raise ProjregError(f"unknown model {name!r}; choose from {', '.join(sorted(MODEL_CONFIGS))}")
    return SSJMFlow(**MODEL_CONFIGS[name], use_ssjm=use_ssjm)


def count_parameters(model: nn.Module) -> int:
    """Number of scalar parameters of ``model`` (trainable or not)."""
    return sum(p.numel() for p in model.parameters())
