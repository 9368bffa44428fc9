"""Matching, warping, upsampling and flow propagation: exact values, recovered shifts, gradchecks."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from projreg import ProjregError
from projreg.model.matching import (
    ConvexUpsampler,
    bilinear_upsample_flow,
    convex_upsample,
    coords_grid,
    flow_warp,
    global_correlation_softmax,
    local_correlation_softmax,
    local_window_scores,
    replicate_pad1,
    window_offsets,
)
from projreg.model.propagation import FlowPropagation


def _sharp_texture(c, h, w, seed=0):
    """Random unit features scaled so that a softmax over matches is one-hot to float precision.

    Self score 400 / sqrt(64) = 50; another position scores 50 cos(angle), cos ~ N(0, 1/8), so the
    best wrong match trails by > 25 and carries < 1e-10 of the weight.
    """
    f = torch.randn(1, c, h, w, generator=torch.Generator().manual_seed(seed))
    return 20.0 * f / f.norm(dim=1, keepdim=True)


def test_coords_grid():
    g = coords_grid(2, 3, 4)
    assert g.shape == (2, 2, 3, 4)
    assert g[1, 0, 2, 3] == 3 and g[1, 1, 2, 3] == 2  # channel 0 = x, channel 1 = y
    assert torch.equal(g[0, 0, 0], torch.arange(4.0)) and torch.equal(g[0, 1, :, 0], torch.arange(3.0))


@pytest.mark.parametrize("dx, dy", [(2, 1), (-3, 2), (0, 0)])
def test_global_matching_recovers_integer_translation(dx, dy):
    h, w = 12, 16
    t = _sharp_texture(64, h + abs(dy), w + abs(dx))
    # f1(x + dx, y + dy) = f0(x, y): both are crops of one texture, f0's offset by (dx, dy)
    y0, x0 = max(dy, 0), max(dx, 0)
    y1, x1 = max(-dy, 0), max(-dx, 0)
    f0 = t[:, :, y0 : y0 + h, x0 : x0 + w]
    f1 = t[:, :, y1 : y1 + h, x1 : x1 + w]
    flow, prob = global_correlation_softmax(f0, f1)
    assert flow.shape == (1, 2, h, w) and prob.shape == (1, h * w, h * w)
    torch.testing.assert_close(prob.sum(-1), torch.ones(1, h * w))
    # interior: pixels whose match lies inside img1
    ys = slice(max(-dy, 0), h - max(dy, 0))
    xs = slice(max(-dx, 0), w - max(dx, 0))
    assert (flow[0, 0, ys, xs] - dx).abs().max() < 1e-3
    assert (flow[0, 1, ys, xs] - dy).abs().max() < 1e-3


def test_local_matching_recovers_small_shift_and_stays_in_window():
    h, w, dx, dy, r = 10, 12, 1, -2, 3
    t = _sharp_texture(64, h + 2, w + 1, seed=1)
    f0 = t[:, :, 0:h, 1 : 1 + w]  # f1(x + 1, y - 2) = f0(x, y)
    f1 = t[:, :, 2 : 2 + h, 0:w]
    flow, prob = local_correlation_softmax(f0, f1, radius=r)
    assert prob.shape == (1, (2 * r + 1) ** 2, h, w)
    torch.testing.assert_close(prob.sum(1), torch.ones(1, h, w))
    assert (flow[0, 0, 2:, : w - 1] - dx).abs().max() < 1e-3
    assert (flow[0, 1, 2:, : w - 1] - dy).abs().max() < 1e-3
    assert flow.abs().max() <= r + 1e-6
    # neighbours outside the image get exactly zero probability: pixel (0, 0) only sees dx, dy >= 0
    offs = window_offsets(r)
    outside = (offs[:, 0] < 0) | (offs[:, 1] < 0)
    assert prob[0, outside, 0, 0].abs().max() == 0.0


def test_window_offsets_order():
    offs = window_offsets(1)
    assert offs.tolist()[:4] == [[-1, -1], [0, -1], [1, -1], [-1, 0]]
    assert offs[4].tolist() == [0, 0]


def test_flow_warp_integer_flow_is_exact_shift_with_zero_outside():
    f = torch.arange(2 * 5 * 6, dtype=torch.float64).view(1, 2, 5, 6)
    flow = torch.zeros(1, 2, 5, 6, dtype=torch.float64)
    flow[:, 0], flow[:, 1] = 2.0, -1.0
    out = flow_warp(f, flow)
    torch.testing.assert_close(out[:, :, 1:, :4], f[:, :, :4, 2:])  # out(x, y) = f(x + 2, y - 1)
    assert out[:, :, 0].abs().max() == 0 and out[:, :, :, 4:].abs().max() == 0


def test_flow_warp_fractional_flow_interpolates_at_pixel_centres():
    # a feature equal to its x coordinate: sampling at x + 0.25 must give exactly x + 0.25
    f = coords_grid(1, 4, 7, dtype=torch.float64)[:, :1].contiguous()
    flow = torch.zeros(1, 2, 4, 7, dtype=torch.float64)
    flow[:, 0] = 0.25
    out = flow_warp(f, flow)
    torch.testing.assert_close(out[0, 0, :, :-1], f[0, 0, :, :-1] + 0.25)


def test_flow_warp_rejects_mismatched_flow():
    with pytest.raises(ProjregError):
        flow_warp(torch.zeros(1, 3, 4, 4), torch.zeros(1, 2, 4, 5))


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 4), st.integers(1, 5), st.integers(1, 5), st.floats(-20, 20), st.floats(-20, 20))
def test_convex_upsample_of_constant_flow_is_exact_everywhere(f, h, w, u, v):
    flow = torch.tensor([u, v], dtype=torch.float64).view(1, 2, 1, 1).expand(1, 2, h, w)
    mask = torch.randn(1, 9 * f * f, h, w, dtype=torch.float64, generator=torch.Generator().manual_seed(h * w))
    up = convex_upsample(flow, mask, f)
    assert up.shape == (1, 2, h * f, w * f)
    torch.testing.assert_close(up[0, 0], torch.full((h * f, w * f), f * u, dtype=torch.float64))
    torch.testing.assert_close(up[0, 1], torch.full((h * f, w * f), f * v, dtype=torch.float64))


def test_replicate_pad1_is_f_pad_replicate_forward_and_backward():
    x = torch.randn(2, 3, 4, 6, dtype=torch.float64, requires_grad=True)
    ours, theirs = replicate_pad1(x), torch.nn.functional.pad(x, (1, 1, 1, 1), mode="replicate")
    assert torch.equal(ours, theirs)
    weights = torch.randn(theirs.shape, dtype=torch.float64)
    (grad_ours,) = torch.autograd.grad((ours * weights).sum(), x)
    (grad_theirs,) = torch.autograd.grad((theirs * weights).sum(), x)
    torch.testing.assert_close(grad_ours, grad_theirs)


def test_convex_upsample_centre_weights_repeat_each_cell():
    f, h, w = 4, 3, 5
    flow = torch.randn(2, 2, h, w, dtype=torch.float64)
    mask = torch.full((2, 9, f, f, h, w), -1e4, dtype=torch.float64)
    mask[:, 4] = 0.0  # all weight on the centre of the 3x3 neighbourhood
    up = convex_upsample(flow, mask.view(2, 9 * f * f, h, w), f)
    expected = f * flow.repeat_interleave(f, dim=2).repeat_interleave(f, dim=3)
    torch.testing.assert_close(up, expected)


def test_convex_upsample_right_weights_take_right_neighbour():
    f, h, w = 2, 2, 3
    flow = torch.randn(1, 2, h, w, dtype=torch.float64)
    mask = torch.full((1, 9, f, f, h, w), -1e4, dtype=torch.float64)
    mask[:, 5] = 0.0  # neighbour (dx, dy) = (1, 0), replicate-padded at the right border
    up = convex_upsample(flow, mask.view(1, 9 * f * f, h, w), f)
    right = torch.cat([flow[..., 1:], flow[..., -1:]], dim=-1)
    torch.testing.assert_close(up[..., ::f, ::f], f * right)


def test_convex_upsample_sub_pixel_rows_and_columns():
    # fine row i of a cell takes the neighbour above (i = 0) or below (i = 1); columns do not matter
    f, h, w = 2, 3, 4
    flow = torch.randn(1, 2, h, w, dtype=torch.float64)
    mask = torch.full((1, 9, f, f, h, w), -1e4, dtype=torch.float64)
    mask[:, 1, 0] = 0.0  # neighbour (dx, dy) = (0, -1)
    mask[:, 7, 1] = 0.0  # neighbour (dx, dy) = (0, +1)
    up = convex_upsample(flow, mask.view(1, 9 * f * f, h, w), f)
    above = torch.cat([flow[:, :, :1], flow[:, :, :-1]], dim=2)
    below = torch.cat([flow[:, :, 1:], flow[:, :, -1:]], dim=2)
    for j in range(f):
        torch.testing.assert_close(up[:, :, 0::f, j::f], f * above)
        torch.testing.assert_close(up[:, :, 1::f, j::f], f * below)


def test_bilinear_upsample_flow_maps_cell_centres():
    # coarse field u(xc) = xc; fine pixel xf lies at coarse xc = (xf - (f-1)/2) / f
    f = 8
    coarse = coords_grid(1, 3, 5, dtype=torch.float64)
    up = bilinear_upsample_flow(coarse, f)
    xf = torch.arange(5 * f, dtype=torch.float64)
    interior = slice(f, 4 * f)
    torch.testing.assert_close(up[0, 0, 0, interior], (xf - (f - 1) / 2)[interior])


def test_gradcheck_global_correlation_softmax():
    g = torch.Generator().manual_seed(0)
    f0 = torch.randn(1, 3, 3, 4, dtype=torch.float64, generator=g, requires_grad=True)
    f1 = torch.randn(1, 3, 3, 4, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: global_correlation_softmax(a, b)[0], (f0, f1))


def test_gradcheck_local_correlation_softmax_custom_backward():
    g = torch.Generator().manual_seed(0)
    f0 = torch.randn(2, 3, 4, 5, dtype=torch.float64, generator=g, requires_grad=True)
    f1 = torch.randn(2, 3, 4, 5, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: local_correlation_softmax(a, b, 2)[0], (f0, f1))


def test_gradcheck_convex_upsample():
    g = torch.Generator().manual_seed(0)
    flow = torch.randn(1, 2, 2, 3, dtype=torch.float64, generator=g, requires_grad=True)
    mask = torch.randn(1, 9 * 4, 2, 3, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, m: convex_upsample(a, m, 2), (flow, mask))


def test_convex_upsampler_module_shape():
    up = ConvexUpsampler(feature_channels=8, hidden_channels=16, factor=4)
    out = up(torch.randn(2, 2, 3, 5), torch.randn(2, 8, 3, 5))
    assert out.shape == (2, 2, 12, 20)


@pytest.mark.parametrize("radius", [None, 1, 2])
def test_propagation_keeps_constant_flow(radius):
    # attention weights are a convex combination (zero outside the image), so a constant stays constant
    prop = FlowPropagation(channels=8, radius=radius).double()
    feat = torch.randn(2, 8, 5, 6, dtype=torch.float64)
    flow = torch.tensor([1.5, -2.0], dtype=torch.float64).view(1, 2, 1, 1).expand(2, 2, 5, 6)
    torch.testing.assert_close(prop(feat, flow), flow.contiguous())


def test_global_propagation_copies_flow_from_similar_features():
    # two feature clusters; pixels of the first carry flow 4, of the second flow -1: each pixel gets its own
    prop = FlowPropagation(channels=4, radius=None).double()
    feat = torch.zeros(1, 4, 4, 4, dtype=torch.float64)
    feat[:, 0, :, :2] = 30.0
    feat[:, 1, :, 2:] = 30.0
    flow = torch.zeros(1, 2, 4, 4, dtype=torch.float64)
    flow[:, 0, :, :2] = 4.0
    flow[:, 0, :, 2:] = -1.0
    flow[:, 0, 0, 0] = 100.0  # one outlier among eight
    out = prop(feat, flow)
    assert (out[0, 0, :, 2:] + 1.0).abs().max() < 1e-6
    torch.testing.assert_close(out[0, 0, :, :2], torch.full((4, 2), (7 * 4.0 + 100.0) / 8, dtype=torch.float64))


@pytest.mark.parametrize(("radius", "h", "w"), [(1, 5, 7), (2, 6, 3), (4, 9, 12)])
def test_window_scores_by_row_products_equal_the_per_offset_products(radius, h, w):
    """Inference and export take the window scores from one matrix product per window row (the
    band of each product); training from the per-offset products of the autograd function."""
    g = torch.Generator().manual_seed(radius)
    f0, f1 = torch.randn(2, 8, h, w, generator=g), torch.randn(2, 8, h, w, generator=g)
    with torch.no_grad():
        banded = local_window_scores(f0, f1, radius)  # [B, K, H, W]
    per_offset = local_window_scores(f0.requires_grad_(), f1, radius).detach()
    inside = torch.isfinite(per_offset)
    assert torch.equal(inside, torch.isfinite(banded))
    torch.testing.assert_close(banded[inside], per_offset[inside], rtol=1e-5, atol=1e-5)
    # by hand: offset (dx, dy) = (1, -1) at pixel (x, y) = (2, 3) compares f0[3, 2] with f1[2, 3]
    k = (radius - 1) * (2 * radius + 1) + radius + 1
    if 3 < h and 3 < w:
        expected = (f0[:, :, 3, 2] * f1[:, :, 2, 3]).sum(1) / 8**0.5
        torch.testing.assert_close(banded[:, k, 3, 2], expected.detach(), rtol=1e-5, atol=1e-5)
