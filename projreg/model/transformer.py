"""Feature transformer: self- and cross-attention between the projected and the captured feature maps.

Each layer is a self-attention sub-layer followed by a cross-attention sub-layer with a feed-forward
network; img0 attends img1 and img1 attends img0 with the same weights, both directions in one batch.
Attention is single-head dot-product attention inside ``attn_splits x attn_splits`` windows; every
second layer shifts the windows by half a window (with a mask so that tokens wrapped around the border
do not see each other), so information crosses window borders as in Swin / GMFlow.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from ..errors import ProjregError


def sine_position_encoding(b: int, c: int, h: int, w: int, device=None, dtype=None) -> torch.Tensor:
    """2-D sine/cosine positional encoding (DETR style), positions normalised to (0, 2 pi].

    Args:
        b, c, h, w: output shape; ``c`` must be a multiple of 4 (half the channels encode y, half x).

    Returns:
        ``[B, C, H, W]``: channels ``[0, C/2)`` encode the row, ``[C/2, C)`` the column, alternating
        sin and cos at geometrically spaced frequencies.

    Convention: pixel ``(x, y)`` of the feature map, y down, x right.
    """
    if c % 4 != 0:
        raise ProjregError(f"positional encoding needs channels divisible by 4, got {c}")
    half = c // 2
    scale = 2.0 * math.pi
    ys = torch.arange(1, h + 1, device=device, dtype=torch.float32) / h * scale  # [H]
    xs = torch.arange(1, w + 1, device=device, dtype=torch.float32) / w * scale  # [W]
    i = torch.arange(half, device=device, dtype=torch.float32)
    freq = 10000.0 ** (2.0 * torch.div(i, 2, rounding_mode="floor") / half)  # [C/2]
    py = ys[:, None] / freq  # [H, C/2]
    px = xs[:, None] / freq  # [W, C/2]
    py = torch.where(i.remainder(2) == 0, py.sin(), py.cos())
    px = torch.where(i.remainder(2) == 0, px.sin(), px.cos())
    pos = torch.cat([py.t()[:, :, None].expand(half, h, w), px.t()[:, None, :].expand(half, h, w)], dim=0)
    return pos.to(dtype or torch.float32)[None].expand(b, c, h, w)


def split_windows(x: torch.Tensor, num_splits: int) -> torch.Tensor:
    """``[B, H, W, C]`` -> ``[B * s * s, H/s * W/s, C]``: the ``s x s`` windows as token sequences."""
    b, h, w, c = x.shape
    s = num_splits
    x = x.view(b, s, h // s, s, w // s, c).permute(0, 1, 3, 2, 4, 5)  # [B, s, s, H/s, W/s, C]
    return x.reshape(b * s * s, (h // s) * (w // s), c)


def merge_windows(x: torch.Tensor, num_splits: int, h: int, w: int) -> torch.Tensor:
    """Inverse of :func:`split_windows`: ``[B * s * s, H/s * W/s, C]`` -> ``[B, H, W, C]``."""
    s = num_splits
    c = x.shape[-1]
    x = x.view(-1, s, s, h // s, w // s, c).permute(0, 1, 3, 2, 4, 5)  # [B, s, H/s, s, W/s, C]
    return x.reshape(-1, h, w, c)


def shifted_window_mask(h: int, w: int, num_splits: int, device=None) -> torch.Tensor:
    """Which token pairs of a shifted window may attend each other.

    After rolling the map by half a window up and left, the last row and column of windows hold
    tokens from opposite borders of the image; those must not attend each other.

    Returns:
        bool ``[s * s, T, T]`` with ``T = H/s * W/s``: true where attention is allowed.
    """
    wh, ww = h // num_splits, w // num_splits
    # rows (columns) fall in three bands: [0, h - wh), [h - wh, h - wh/2), [h - wh/2, h); comparisons
    # rather than slice assignments, so the mask follows a symbolic size in an exported graph
    ys = torch.arange(h, device=device)
    xs = torch.arange(w, device=device)
    band_y = (ys >= h - wh).long() + (ys >= h - wh // 2).long()  # [H]
    band_x = (xs >= w - ww).long() + (xs >= w - ww // 2).long()  # [W]
    label = 3 * band_y[:, None] + band_x[None, :]  # [H, W]
    win = split_windows(label[None, :, :, None], num_splits)[..., 0]  # [s*s, T]
    return win[:, :, None] == win[:, None, :]


def roll2d(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """``torch.roll(x, (dy, dx), dims=(1, 2))`` for ``[B, H, W, C]`` and ``0 <= dy <= H``, ``0 <= dx <= W``.

    Written as two slices and a concatenation per axis: ``torch.roll`` with shifts that depend on the
    input's size does not export to ONNX (docs/model.md, "Export").
    """
    h, w = x.shape[1], x.shape[2]
    x = torch.cat([x[:, h - dy :], x[:, : h - dy]], dim=1)
    return torch.cat([x[:, :, w - dx :], x[:, :, : w - dx]], dim=2)


def window_attention(
    q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, h: int, w: int, num_splits: int, shifted: bool
) -> torch.Tensor:
    """Single-head scaled dot-product attention inside (optionally shifted) windows.

    Args:
        q, k, v: ``[B, H*W, C]`` tokens in row-major order of an ``H x W`` map.
        h, w: map size; both multiples of ``num_splits``.
        num_splits: windows per side (1: global attention).
        shifted: shift the windows by half a window (ignored when ``num_splits == 1``).

    Returns:
        ``[B, H*W, C]``.
    """
    b, _, c = q.shape
    shifted = shifted and num_splits > 1
    sh, sw = (h // num_splits) // 2, (w // num_splits) // 2  # the windows move up and left by half a window
    out = []
    for t in (q, k, v):
        t = t.view(b, h, w, c)
        if shifted:
            t = roll2d(t, h - sh, w - sw)
        out.append(split_windows(t, num_splits))  # [B*s*s, T, C]
    qw, kw, vw = out
    scores = torch.matmul(qw / math.sqrt(c), kw.transpose(1, 2))  # [B*s*s, T, T]
    if shifted:
        allowed = shifted_window_mask(h, w, num_splits, device=q.device)  # [s*s, T, T]
        t = allowed.shape[-1]
        # an additive bias rather than masked_fill (onnxruntime's Where took 5-9 ms a layer): -1e9 in
        # float32 (-inf once cast to half) sends exp() to exactly 0, as -inf does
        bias = (~allowed).to(torch.float32).mul(-1e9).to(scores.dtype)  # [s*s, T, T]
        scores = (scores.view(b, -1, t, t) + bias).view(-1, t, t)
    msg = torch.matmul(torch.softmax(scores, dim=-1), vw)  # [B*s*s, T, C]
    msg = merge_windows(msg, num_splits, h, w)  # [B, H, W, C]
    if shifted:
        msg = roll2d(msg, sh, sw)
    return msg.reshape(b, h * w, c)


class AttentionLayer(nn.Module):
    """One attention sub-layer: ``source`` attends ``target``, then an optional feed-forward network.

    ``out = source + norm(merge(attn(q(source), k(target), v(target))))``; with the FFN, the message
    is refined from ``[source; message]`` (expansion ``ffn_dim_expansion``) before the residual.

    Convention: tokens ``[B, H*W, C]``.
    """

    def __init__(self, channels: int, ffn_dim_expansion: int, with_ffn: bool) -> None:
        super().__init__()
        self.q = nn.Linear(channels, channels, bias=False)
        self.k = nn.Linear(channels, channels, bias=False)
        self.v = nn.Linear(channels, channels, bias=False)
        self.merge = nn.Linear(channels, channels, bias=False)
        self.norm1 = nn.LayerNorm(channels)
        self.ffn = None
        if with_ffn:
            hidden = 2 * channels * ffn_dim_expansion
            self.ffn = nn.Sequential(
                nn.Linear(2 * channels, hidden, bias=False),
                nn.GELU(),
                nn.Linear(hidden, channels, bias=False),
            )
            self.norm2 = nn.LayerNorm(channels)

    def forward(
        self, source: torch.Tensor, target: torch.Tensor, h: int, w: int, num_splits: int, shifted: bool
    ) -> torch.Tensor:
        q, k, v = self.q(source), self.k(target), self.v(target)  # [B, H*W, C]
        msg = self.norm1(self.merge(window_attention(q, k, v, h, w, num_splits, shifted)))  # [B, H*W, C]
        if self.ffn is not None:
            msg = self.norm2(self.ffn(torch.cat([source, msg], dim=-1)))  # [B, H*W, C]
        return source + msg


class FeatureTransformer(nn.Module):
    """``num_layers`` x (self-attention, cross-attention + FFN); odd layers use shifted windows.

    Args:
        channels: feature channels C.
        num_layers: number of (self, cross) layer pairs.
        ffn_dim_expansion: FFN hidden width is ``2 * C * ffn_dim_expansion``.
        attn_splits: windows per side.

    Convention: ``forward(f0, f1)`` takes and returns two ``[B, C, H, W]`` maps (projected, captured),
    ``H`` and ``W`` multiples of ``attn_splits``; a sine positional encoding is added first.
    """

    def __init__(self, channels: int, num_layers: int, ffn_dim_expansion: int, attn_splits: int) -> None:
        super().__init__()
        self.attn_splits = attn_splits
        self.checkpointing = True  # recompute each layer pair's attention in backward (set by training)
        self.self_layers = nn.ModuleList(
            [AttentionLayer(channels, ffn_dim_expansion, with_ffn=False) for _ in range(num_layers)]
        )
        self.cross_layers = nn.ModuleList(
            [AttentionLayer(channels, ffn_dim_expansion, with_ffn=True) for _ in range(num_layers)]
        )

    def forward(self, f0: torch.Tensor, f1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, c, h, w = f0.shape
        s = self.attn_splits
        if h % s or w % s:
            raise ProjregError(f"feature map {h}x{w} is not divisible by attn_splits={s}")
        pos = sine_position_encoding(b, c, h, w, device=f0.device, dtype=f0.dtype)  # [B, C, H, W]
        x = torch.cat([f0 + pos, f1 + pos], dim=0).flatten(2).transpose(1, 2)  # [2B, H*W, C]
        for i, (self_layer, cross_layer) in enumerate(zip(self.self_layers, self.cross_layers, strict=True)):

            def pair(x: torch.Tensor, self_layer=self_layer, cross_layer=cross_layer, shifted=i % 2 == 1):
                x = self_layer(x, x, h, w, s, shifted)  # [2B, H*W, C]
                swapped = torch.cat([x[b:], x[:b]], dim=0)  # img0 attends img1 and vice versa
                return cross_layer(x, swapped, h, w, s, shifted)  # [2B, H*W, C]

            # training keeps only each layer pair's input and recomputes its attention maps in backward:
            # small at batch 8, 384x512 peaks at 8.8 GiB without this (costs ~15% of a CPU step)
            recompute = self.checkpointing and self.training and torch.is_grad_enabled()
            x = checkpoint(pair, x, use_reentrant=False) if recompute else pair(x)
        x = x.transpose(1, 2).reshape(2 * b, c, h, w)  # [2B, C, H, W]
        return x[:b], x[b:]
