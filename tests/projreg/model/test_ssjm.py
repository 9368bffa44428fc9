"""SSJM against the formula of DESIGN.md section 9, computed by hand in numpy."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from projreg import ProjregError
from projreg.model.ssjm import SSJM, saliency_energy


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _ssjm_numpy(x, lam, w_max, w_mean, bias):
    """The formula with a 7x7 kernel that is zero except its centre taps (so conv = pointwise)."""
    mu = x.mean(axis=(2, 3), keepdims=True)
    var = ((x - mu) ** 2).mean(axis=(2, 3), keepdims=True)
    e = (x - mu) ** 2 / (4 * (var + lam)) + 0.5
    xs = x * _sigmoid(e)
    m = _sigmoid(w_max * xs.max(axis=1, keepdims=True) + w_mean * xs.mean(axis=1, keepdims=True) + bias)
    return xs * m


def _ssjm_with_centre_kernel(lam, w_max, w_mean, bias):
    mod = SSJM(lam=lam).double()
    with torch.no_grad():
        mod.conv.weight.zero_()
        mod.conv.weight[0, 0, 3, 3] = w_max
        mod.conv.weight[0, 1, 3, 3] = w_mean
        mod.conv.bias.fill_(bias)
    return mod


def test_ssjm_hand_computed_zero_kernel():
    x = np.array([[[[1.0, 2.0], [3.0, 4.0]], [[0.0, 0.0], [0.0, 5.0]]]])  # [1, 2, 2, 2]
    # channel 0: mu 2.5, var 1.25; channel 1: mu 1.25, var 4.6875
    e0 = np.array([[2.25, 0.25], [0.25, 2.25]]) / (4 * 1.25) + 0.5
    e1 = np.array([[1.5625, 1.5625], [1.5625, 14.0625]]) / (4 * 4.6875) + 0.5
    xs = x * _sigmoid(np.stack([e0, e1])[None])
    expected = xs * _sigmoid(0.3)  # zero kernel: the mask is sigmoid(bias) everywhere
    mod = _ssjm_with_centre_kernel(lam=1e-12, w_max=0.0, w_mean=0.0, bias=0.3)
    out = mod(torch.from_numpy(x)).detach().numpy()
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-12)


def test_ssjm_matches_numpy_with_known_kernel():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 3, 4, 5)) * 3.0
    mod = _ssjm_with_centre_kernel(lam=1e-4, w_max=0.7, w_mean=-1.3, bias=0.2)
    out = mod(torch.from_numpy(x)).detach().numpy()
    np.testing.assert_allclose(out, _ssjm_numpy(x, 1e-4, 0.7, -1.3, 0.2), rtol=1e-10, atol=1e-12)


def test_ssjm_kernel_is_7x7_with_padding_3():
    mod = SSJM()
    assert tuple(mod.conv.weight.shape) == (1, 2, 7, 7)
    assert mod.conv.padding == (3, 3) and mod.conv.bias is not None
    assert sum(p.numel() for p in mod.parameters()) == 2 * 49 + 1


def test_ssjm_off_centre_tap_reads_right_neighbour_with_zero_padding():
    # kernel tap (row 3, col 4) of the max channel reads the pixel to the right (cross-correlation)
    x = np.ones((1, 1, 3, 3))
    x[0, 0, 1, 2] = 3.0
    mod = SSJM(lam=1e-4).double()
    with torch.no_grad():
        mod.conv.weight.zero_()
        mod.conv.weight[0, 0, 3, 4] = 2.0
        mod.conv.bias.fill_(-1.0)
    xs = x * _sigmoid(saliency_energy(torch.from_numpy(x), 1e-4).numpy())
    right = np.zeros_like(xs)
    right[..., :, :-1] = xs[..., :, 1:]  # the last column sees the zero padding
    expected = xs * _sigmoid(2.0 * right - 1.0)
    np.testing.assert_allclose(mod(torch.from_numpy(x)).detach().numpy(), expected, rtol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 4), st.integers(2, 5), st.integers(2, 5), st.integers(0, 10_000))
def test_saliency_energy_mean_is_half_plus_quarter(c, h, w, seed):
    # mean over pixels of (X - mu)^2 / (4 (var + lam)) is var / (4 (var + lam))
    x = torch.randn(2, c, h, w, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    lam = 1e-4
    var = x.var(dim=(2, 3), unbiased=False)
    e = saliency_energy(x, lam)
    torch.testing.assert_close(e.mean(dim=(2, 3)), 0.5 + var / (4 * (var + lam)))
    assert (e >= 0.5).all()


def test_ssjm_batch_concatenation_equals_separate_calls():
    torch.manual_seed(0)
    mod = SSJM()
    a, b = torch.randn(2, 8, 6, 7), 5.0 * torch.randn(2, 8, 6, 7) + 1.0
    both = mod(torch.cat([a, b]))
    torch.testing.assert_close(both[:2], mod(a))
    torch.testing.assert_close(both[2:], mod(b))


def test_ssjm_gradcheck():
    torch.manual_seed(0)
    mod = SSJM(lam=1e-2).double()
    x = torch.randn(1, 3, 4, 5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(mod, (x,))


def test_ssjm_rejects_non_positive_lambda():
    with pytest.raises(ProjregError):
        SSJM(lam=0.0)
