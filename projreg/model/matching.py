"""Matching and flow geometry: global and local correlation, warping, flow upsampling.

Everything here is a plain function except :class:`ConvexUpsampler`, which predicts the upsampling
weights. Flows are forward (img0 = projected -> img1 = captured) in pixels of the map they live on,
channel 0 = u (x, right), channel 1 = v (y, down); pixel centres are at integer coordinates.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import ProjregError


def coords_grid(b: int, h: int, w: int, device=None, dtype=None) -> torch.Tensor:
    """Pixel coordinates of an ``h x w`` map.

    Returns:
        ``[B, 2, H, W]`` with ``grid[:, 0, y, x] = x`` and ``grid[:, 1, y, x] = y``.

    Convention: pixel centres at integer coordinates, origin top-left.
    """
    ys, xs = torch.meshgrid(
        torch.arange(h, device=device, dtype=dtype or torch.float32),
        torch.arange(w, device=device, dtype=dtype or torch.float32),
        indexing="ij",
    )
    return torch.stack([xs, ys], dim=0)[None].expand(b, 2, h, w)


def global_correlation_softmax(f0: torch.Tensor, f1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Flow as the softmax-expected match of every img0 position over all img1 positions.

    ``prob = softmax_j(<f0_i, f1_j> / sqrt(C))``, ``flow_i = sum_j prob_ij * p_j - p_i``.

    Args:
        f0, f1: ``[B, C, H, W]`` features of img0 (projected) and img1 (captured).

    Returns:
        ``(flow [B, 2, H, W], prob [B, H*W, H*W])``; ``prob[b, i, j]``: img0 pixel i matches img1
        pixel j, pixels in row-major order.

    Convention: flow img0 -> img1 in pixels of this map.
    """
    b, c, h, w = f0.shape
    q = f0.flatten(2).transpose(1, 2) / math.sqrt(c)  # [B, H*W, C]
    k = f1.flatten(2)  # [B, C, H*W]
    prob = torch.softmax(torch.bmm(q, k), dim=-1)  # [B, H*W, H*W]
    grid = coords_grid(b, h, w, device=f0.device, dtype=f0.dtype)  # [B, 2, H, W]
    match = torch.bmm(prob, grid.flatten(2).transpose(1, 2))  # [B, H*W, 2]
    flow = match.transpose(1, 2).reshape(b, 2, h, w) - grid  # [B, 2, H, W]
    return flow, prob


def window_offsets(radius: int, device=None, dtype=None) -> torch.Tensor:
    """The ``(2r+1)^2`` offsets ``(dx, dy)`` of a square window, dy outer, dx inner: ``[K, 2]``."""
    r = torch.arange(-radius, radius + 1, device=device, dtype=dtype or torch.float32)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    return torch.stack([dx.flatten(), dy.flatten()], dim=1)


def _window_slices(r: int, h: int, w: int):
    """Slices of an r-padded map that shift it by each window offset, in :func:`window_offsets` order."""
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            yield slice(r + dy, r + dy + h), slice(r + dx, r + dx + w)


class _WindowDot(torch.autograd.Function):
    """``out[:, k] = sum_c f0 * shift_k(f1)`` for the window offsets k, with a hand-written backward.

    Autograd through 81 slices of a padded tensor allocates and fills a padded gradient per offset;
    accumulating in place here makes the refinement's backward several times cheaper.
    """

    @staticmethod
    def forward(ctx, f0: torch.Tensor, f1: torch.Tensor, radius: int) -> torch.Tensor:
        b, _, h, w = f0.shape
        r = radius
        f1p = F.pad(f1, (r, r, r, r))  # [B, C, H+2r, W+2r]
        prod = torch.empty_like(f0)  # reused: a fresh large tensor per offset costs page faults
        out = f0.new_empty((2 * r + 1) ** 2, b, h, w)  # [K, B, H, W]
        for k, (ys, xs) in enumerate(_window_slices(r, h, w)):
            torch.sum(torch.mul(f0, f1p[:, :, ys, xs], out=prod), dim=1, out=out[k])
        ctx.save_for_backward(f0, f1p)
        ctx.radius = r
        return out.transpose(0, 1).contiguous()  # [B, K, H, W]

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: torch.Tensor):
        f0, f1p = ctx.saved_tensors
        r = ctx.radius
        _, _, h, w = f0.shape
        grad_f0 = torch.zeros_like(f0) if ctx.needs_input_grad[0] else None
        grad_f1p = torch.zeros_like(f1p) if ctx.needs_input_grad[1] else None
        for k, (ys, xs) in enumerate(_window_slices(r, h, w)):
            g = grad[:, k : k + 1]  # [B, 1, H, W]
            if grad_f0 is not None:
                grad_f0.addcmul_(g, f1p[:, :, ys, xs])
            if grad_f1p is not None:
                grad_f1p[:, :, ys, xs].addcmul_(g, f0)
        grad_f1 = None if grad_f1p is None else grad_f1p[:, :, r : r + h, r : r + w]
        return grad_f0, grad_f1, None


def local_window_scores(f0: torch.Tensor, f1: torch.Tensor, radius: int) -> torch.Tensor:
    """Scaled dot products of each img0 pixel with the img1 pixels in its ``(2r+1)^2`` window.

    Returns:
        ``[B, K, H, W]`` in the order of :func:`window_offsets`; -inf where the neighbour lies outside
        the image, so a softmax over K ignores it (the centre is always inside).

    Convention: f0, f1 ``[B, C, H, W]``; score k at ``(x, y)`` compares f0(x, y) with f1(x+dx, y+dy).
    """
    if radius < 1:
        raise ProjregError(f"window radius must be >= 1, got {radius}")
    _, c, h, w = f0.shape
    r = radius
    inside = F.pad(torch.ones(h, w, device=f0.device, dtype=torch.bool), (r, r, r, r))  # [H+2r, W+2r]
    outside = ~torch.stack([inside[ys, xs] for ys, xs in _window_slices(r, h, w)], dim=0)  # [K, H, W]
    dtype = torch.promote_types(f0.dtype, f1.dtype)
    f0, f1 = f0.to(dtype) / math.sqrt(c), f1.to(dtype).contiguous()
    if torch.is_grad_enabled() and (f0.requires_grad or f1.requires_grad):
        scores = _WindowDot.apply(f0, f1, r)  # [B, K, H, W]
    else:  # inference and export: row products (the exporter traces ``out=`` arguments very slowly)
        scores = _banded_window_dot(f0, f1, r)  # [B, K, H, W]
    return scores.masked_fill(outside, float("-inf"))


def _banded_window_dot(f0: torch.Tensor, f1: torch.Tensor, radius: int) -> torch.Tensor:
    """:class:`_WindowDot`'s forward as one matrix product per window row ``dy``.

    Each row of f0 against the row ``dy`` below it in r-padded f1 gives a ``[W, W+2r]`` product
    whose band ``(x, x + j)``, ``j < 2r + 1``, holds the window's column offsets; the band is read by
    flattening the product, padding it by ``W`` and reshaping to rows of ``W + 2r + 1`` (the band's
    diagonal becomes the first ``2r + 1`` columns). About 14x the multiply-adds of the 81 per-offset
    products at radius 4 on a 128-wide map, but in matrix products instead of 81 element-wise passes
    and channel sums over the map: 10x faster in onnxruntime on a 96 x 128 map, 3-4x in PyTorch
    (docs/history/2026-11-log.md, "session 9"); equal up to float rounding.

    Convention: f0, f1 ``[B, C, H, W]`` -> ``[B, K, H, W]`` in :func:`window_offsets` order.
    """
    b, c, h, w = f0.shape
    r, k = radius, 2 * radius + 1
    rows0 = f0.permute(0, 2, 3, 1).reshape(b * h, w, c)  # [B*H, W, C]
    f1p = F.pad(f1, (r, r, r, r)).permute(0, 2, 1, 3)  # [B, H+2r, C, W+2r]
    bands = []
    for dy in range(k):
        prod = torch.matmul(rows0, f1p[:, dy : dy + h].reshape(b * h, c, w + 2 * r))  # [B*H, W, W+2r]
        flat = F.pad(prod.reshape(b * h, w * (w + 2 * r)), (0, w))  # [B*H, W * (W+2r+1)]
        bands.append(flat.reshape(b * h, w, w + 2 * r + 1)[:, :, :k])  # [B*H, W, 2r+1]: dx = -r..r
    scores = torch.stack(bands, dim=2).reshape(b, h, w, k * k)  # [B, H, W, K], dy outer, dx inner
    return scores.permute(0, 3, 1, 2)


def local_window_gather(x: torch.Tensor, prob: torch.Tensor, radius: int) -> torch.Tensor:
    """``out(p) = sum_k prob_k(p) * x(p + offset_k)``: window-weighted sum of a map.

    Args:
        x: ``[B, D, H, W]``.
        prob: ``[B, K, H, W]`` weights in the order of :func:`window_offsets`, zero outside the image.

    Returns:
        ``[B, D, H, W]``.
    """
    b, d, h, w = x.shape
    r = radius
    xp = F.pad(x, (r, r, r, r))  # [B, D, H+2r, W+2r]
    out = torch.zeros_like(x)
    for k, (ys, xs) in enumerate(_window_slices(r, h, w)):
        out = out + prob[:, k : k + 1] * xp[:, :, ys, xs]
    return out


def window_softmax(scores: torch.Tensor) -> torch.Tensor:
    """``torch.softmax(scores, dim=1)`` for window scores ``[B, K, H, W]``, taken over the last axis of
    a ``[B, H, W, K]`` view: onnxruntime's Softmax on a middle axis transposes its input and output
    itself, and here the transposes cancel against the window products' own layout."""
    return torch.softmax(scores.permute(0, 2, 3, 1), dim=-1).permute(0, 3, 1, 2)


def local_correlation_softmax(f0: torch.Tensor, f1: torch.Tensor, radius: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Flow as the softmax-expected offset of each img0 pixel within a ``(2r+1)^2`` img1 window.

    Args:
        f0, f1: ``[B, C, H, W]``; f1 is normally img1 warped by the current flow, so the result is a
            residual flow in ``[-r, r]``.
        radius: window radius r.

    Returns:
        ``(flow [B, 2, H, W], prob [B, K, H, W])``, K = ``(2r+1)^2`` in :func:`window_offsets` order.

    Convention: flow img0 -> img1 in pixels of this map.
    """
    prob = torch.softmax(local_window_scores(f0, f1, radius).permute(0, 2, 3, 1), dim=-1)  # [B, H, W, K]
    offsets = window_offsets(radius, device=f0.device, dtype=prob.dtype)  # [K, 2]
    flow = torch.matmul(prob, offsets).permute(0, 3, 1, 2)  # [B, 2, H, W]
    return flow, prob.permute(0, 3, 1, 2)


def flow_warp(feature: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """Sample ``feature`` (of img1) at ``p + flow(p)``: img1 brought onto the img0 grid.

    Bilinear, zero outside the map; ``grid_sample`` with ``align_corners=True`` so that normalised -1
    and +1 are the centres of the first and last pixels (pixel centres at integer coordinates).

    Args:
        feature: ``[B, C, H, W]``.
        flow: ``[B, 2, H, W]`` img0 -> img1 in pixels.

    Returns:
        ``[B, C, H, W]``; ``out[:, :, y, x] = feature at (x + u, y + v)``.
    """
    b, _, h, w = feature.shape
    if flow.shape != (b, 2, h, w):
        raise ProjregError(f"flow shape {tuple(flow.shape)} does not match feature {tuple(feature.shape)}")
    pos = coords_grid(b, h, w, device=flow.device, dtype=flow.dtype) + flow  # [B, 2, H, W]
    gx = 2.0 * pos[:, 0] / max(w - 1, 1) - 1.0  # [B, H, W]
    gy = 2.0 * pos[:, 1] / max(h - 1, 1) - 1.0  # [B, H, W]
    grid = torch.stack([gx, gy], dim=-1)  # [B, H, W, 2]
    return F.grid_sample(feature, grid, mode="bilinear", padding_mode="zeros", align_corners=True)


def bilinear_upsample_flow(flow: torch.Tensor, factor: int) -> torch.Tensor:
    """Upsample a flow by an integer ``factor`` bilinearly and rescale it to the new pixels.

    ``align_corners=False``: coarse pixel i covers fine pixels ``[f*i, f*i + f)``, whose centre
    ``f*i + (f-1)/2`` it lands on, which is how a stride-``f`` encoder sees it.

    Convention: ``[B, 2, h, w]`` -> ``[B, 2, h*f, w*f]``, values multiplied by ``f``.
    """
    return factor * F.interpolate(flow, scale_factor=factor, mode="bilinear", align_corners=False)


def replicate_pad1(x: torch.Tensor) -> torch.Tensor:
    """``[B, C, H, W]`` -> ``[B, C, H+2, W+2]``, each border row and column repeated once: ``F.pad``'s
    replicate mode written with slices, whose backward ``torch.compile`` (torch 2.13, inductor on the CPU)
    gets right; ``F.pad``'s own backward failed there with a stride assertion."""
    x = torch.cat([x[:, :, :1], x, x[:, :, -1:]], dim=2)
    return torch.cat([x[..., :1], x, x[..., -1:]], dim=3)


def convex_upsample(flow: torch.Tensor, mask: torch.Tensor, factor: int) -> torch.Tensor:
    """Upsample a flow as a learned convex combination of its 3x3 coarse neighbourhood (RAFT).

    Each fine pixel of coarse cell ``(x, y)`` is ``sum_k softmax(mask)_k * factor * flow(neighbour_k)``.
    The neighbourhood is replicate-padded at the border, so a constant flow upsamples exactly.

    Args:
        flow: ``[B, 2, h, w]``.
        mask: ``[B, 9 * factor * factor, h, w]`` logits, laid out ``[9, factor (row), factor (col)]``.
        factor: integer upsampling factor.

    Returns:
        ``[B, 2, h*factor, w*factor]`` in fine pixels.
    """
    b, _, h, w = flow.shape
    f = factor
    if mask.shape != (b, 9 * f * f, h, w):
        raise ProjregError(f"mask shape {tuple(mask.shape)} != {(b, 9 * f * f, h, w)}")
    # the softmax written out, normalised after the sum: onnxruntime's Softmax on a middle axis (or a
    # transpose to put the 9 last) took 8-20 ms of a 384 x 512 pair's 236 (docs/history/2026-11-log.md, session 10)
    logits = mask.view(b, 1, 9, f * f, h * w)
    e = torch.exp(logits - logits.amax(dim=2, keepdim=True))  # [B, 1, 9, f*f, h*w]
    padded = replicate_pad1(f * flow)  # [B, 2, h+2, w+2]
    neigh = F.unfold(padded, kernel_size=3).view(b, 2, 9, 1, h * w)  # [B, 2, 9, 1, h*w]
    up = (e * neigh).sum(dim=2) / e.sum(dim=2)  # [B, 2, f*f, h*w]
    return up.view(b, 2, f, f, h, w).permute(0, 1, 4, 2, 5, 3).reshape(b, 2, h * f, w * f)


class ConvexUpsampler(nn.Module):
    """Predicts the convex-upsampling logits from the flow and the img0 feature, then upsamples.

    Args:
        feature_channels: channels of the img0 feature.
        hidden_channels: width of the 3x3 hidden convolution.
        factor: upsampling factor.

    Convention: ``forward(flow [B, 2, h, w], feature [B, C, h, w]) -> [B, 2, h*factor, w*factor]``.
    """

    def __init__(self, feature_channels: int, hidden_channels: int, factor: int) -> None:
        super().__init__()
        self.factor = factor
        self.mask = nn.Sequential(
            nn.Conv2d(2 + feature_channels, hidden_channels, kernel_size=3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden_channels, 9 * factor * factor, kernel_size=1),
        )

    def forward(self, flow: torch.Tensor, feature: torch.Tensor) -> torch.Tensor:
        mask = self.mask(torch.cat([flow, feature], dim=1))  # [B, 9*f*f, h, w]
        return convex_upsample(flow, mask, self.factor)
