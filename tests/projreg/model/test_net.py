"""SSJMFlow and its feature transformer: shapes, sizes, configs, determinism, window masks, overfitting."""

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from projreg import ProjregError
from projreg.model import MODEL_CONFIGS, SSJMFlow, build_model, count_parameters
from projreg.model.transformer import (
    FeatureTransformer,
    merge_windows,
    sine_position_encoding,
    split_windows,
    window_attention,
)
from projreg.training.loss import sequence_loss


def _images(b, h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    return 255 * torch.rand(b, 3, h, w, generator=g), 255 * torch.rand(b, 3, h, w, generator=g)


# --- transformer ------------------------------------------------------------------------------------


@settings(max_examples=20, deadline=None)
@given(st.integers(2, 3), st.integers(1, 3), st.integers(1, 3), st.integers(1, 3))
def test_split_merge_windows_round_trip(s, hs, ws, c):
    x = torch.randn(2, s * hs, s * ws, c)
    win = split_windows(x, s)
    assert win.shape == (2 * s * s, hs * ws, c)
    # window 1 of sample 0 is the top row, second column block
    torch.testing.assert_close(win[1].view(hs, ws, c), x[0, :hs, ws : 2 * ws])
    torch.testing.assert_close(merge_windows(win, s, s * hs, s * ws), x)


def _interaction(h, w, s, shifted):
    """[H*W, H*W] bool: whether output token p depends on value token q."""
    v = torch.randn(1, h * w, 3, dtype=torch.float64, requires_grad=True)
    q = torch.randn(1, h * w, 3, dtype=torch.float64)
    out = window_attention(q, q.clone(), v, h, w, s, shifted)
    rows = []
    for p in range(h * w):
        (g,) = torch.autograd.grad(out[0, p].sum(), v, retain_graph=True)
        rows.append(g[0].abs().sum(-1) > 0)
    return torch.stack(rows)


def _blocks(n, edges):
    """Block label of each index 0..n-1 given the block start edges."""
    return torch.tensor([sum(i >= e for e in edges) for i in range(n)])


@pytest.mark.parametrize("shifted", [False, True])
def test_window_attention_sees_exactly_its_window(shifted):
    h, w, s = 4, 6, 2  # windows 2 x 3; shifted by (1, 1) without wrap-around
    by = _blocks(h, [1, 3] if shifted else [2])
    bx = _blocks(w, [1, 4] if shifted else [3])
    label = (by[:, None] * 10 + bx[None, :]).flatten()
    expected = label[:, None] == label[None, :]
    assert torch.equal(_interaction(h, w, s, shifted), expected)


def test_window_attention_one_split_is_global_softmax_attention():
    q, k, v = (torch.randn(2, 12, 4, dtype=torch.float64) for _ in range(3))
    ref = torch.softmax(q @ k.transpose(1, 2) / 2.0, dim=-1) @ v
    torch.testing.assert_close(window_attention(q, k, v, 3, 4, 1, shifted=True), ref)


def test_sine_position_encoding_values():
    pe = sine_position_encoding(1, 8, 2, 4)
    assert pe.shape == (1, 8, 2, 4)
    # channel 0: sin of the normalised row position 2 pi (y + 1) / H; channel 5: cos of the column's
    torch.testing.assert_close(pe[0, 0, :, 0], torch.sin(torch.tensor([torch.pi, 2 * torch.pi])))
    torch.testing.assert_close(pe[0, 5, 0, :], torch.cos(torch.arange(1, 5) / 4 * 2 * torch.pi))
    with pytest.raises(ProjregError):
        sine_position_encoding(1, 6, 2, 2)


def test_transformer_swapping_inputs_swaps_outputs():
    # shared weights in both directions: img0 attends img1 as img1 attends img0
    torch.manual_seed(0)
    tr = FeatureTransformer(channels=8, num_layers=2, ffn_dim_expansion=2, attn_splits=2).eval()
    a, b = torch.randn(1, 8, 4, 6), torch.randn(1, 8, 4, 6)
    a0, b0 = tr(a, b)
    b1, a1 = tr(b, a)
    torch.testing.assert_close(a0, a1)
    torch.testing.assert_close(b0, b1)


def test_transformer_shifted_layer_carries_information_across_windows():
    # 4x4 map, 2x2 windows: after an unshifted and a shifted layer, token (1, 1) depends on (3, 3)
    torch.manual_seed(0)
    tr = FeatureTransformer(channels=8, num_layers=2, ffn_dim_expansion=1, attn_splits=2).double()
    a = torch.randn(1, 8, 4, 4, dtype=torch.float64, requires_grad=True)
    b = torch.randn(1, 8, 4, 4, dtype=torch.float64, requires_grad=True)
    # a weighted sum over the channels: their plain sum after a layer norm (gain 1, bias 0) is the residual's
    # alone, whose gradient reaches other tokens only by rounding
    weights = torch.arange(1, 9, dtype=torch.float64)
    ga, gb = torch.autograd.grad((tr(a, b)[0][0, :, 1, 1] * weights).sum(), (a, b))
    assert ga[0, :, 3, 3].abs().sum() > 1e-6 and gb[0, :, 3, 3].abs().sum() > 1e-6
    # one unshifted layer keeps token (1, 1) inside its own window
    one = FeatureTransformer(channels=8, num_layers=1, ffn_dim_expansion=1, attn_splits=2).double()
    ga, gb = torch.autograd.grad((one(a, b)[0][0, :, 1, 1] * weights).sum(), (a, b))
    assert ga[0, :, 0, 0].abs().sum() > 1e-6 and gb[0, :, 0, 0].abs().sum() > 1e-6  # its window reaches it
    assert ga[0, :, 2:].abs().sum() == 0 and gb[0, :, :, 2:].abs().sum() == 0


# --- network ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [(37, 53), (64, 96)])
def test_small_output_shapes(size):
    model = build_model("small").eval()
    img0, img1 = _images(2, *size)
    with torch.no_grad():
        preds = model(img0, img1)
    assert len(preds) == 4  # global, propagated, local refinement, refined + propagated
    for p in preds:
        assert p.shape == (2, 2, *size) and torch.isfinite(p).all()


def test_base_output_shape_and_parameter_count():
    model = build_model("base").eval()
    n = count_parameters(model)
    print(f"base: {n:,} parameters")
    assert 4.2e6 <= n <= 5.2e6
    with torch.no_grad():
        preds = model(*_images(1, 37, 53))
    assert [tuple(p.shape) for p in preds] == [(1, 2, 37, 53)] * 2


def test_small_state_dict_size():
    model = build_model("small")
    nbytes = sum(t.numel() * t.element_size() for t in model.state_dict().values())
    print(f"small: {count_parameters(model):,} parameters, state dict {nbytes / 2**20:.2f} MiB")
    assert nbytes < 16 * 2**20


def test_without_ssjm_builds_and_runs():
    model = build_model("small", use_ssjm=False).eval()
    assert model.config["use_ssjm"] is False
    assert not any("ssjm" in name for name, _ in model.named_parameters())
    assert count_parameters(build_model("small")) - count_parameters(model) == 99  # one 7x7x2 conv + bias
    with torch.no_grad():
        preds = model(*_images(1, 33, 41))
    assert preds[-1].shape == (1, 2, 33, 41)


def test_config_rebuilds_the_model():
    model = build_model("small")
    assert model.config == {**MODEL_CONFIGS["small"], "use_ssjm": True, "ssjm_lambda": 1e-4}
    clone = SSJMFlow(**model.config)
    clone.load_state_dict(model.state_dict(), strict=True)
    img0, img1 = _images(1, 32, 48)
    model.eval(), clone.eval()
    with torch.no_grad():
        torch.testing.assert_close(model(img0, img1)[-1], clone(img0, img1)[-1], rtol=0, atol=0)


def test_eval_forward_is_deterministic_and_crop_consistent():
    model = build_model("small").eval()
    img0, img1 = _images(1, 37, 53, seed=3)
    with torch.no_grad():
        a = model(img0, img1)
        b = model(img0, img1)
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)


def test_padding_is_replicate_at_bottom_right_and_cropped_back():
    # 40x56 is padded to 48x64 (multiple 16): same answer as padding by hand and cropping the top-left
    model = build_model("small").eval()
    img0, img1 = _images(1, 40, 56, seed=5)
    with torch.no_grad():
        preds = model(img0, img1)
        padded = model(*(F.pad(x, (0, 8, 0, 8), mode="replicate") for x in (img0, img1)))
    for p, q in zip(preds, padded, strict=True):
        torch.testing.assert_close(p, q[:, :, :40, :56])


def test_autocast_keeps_flow_in_float32():
    model = build_model("small").eval()
    with torch.no_grad(), torch.autocast(device_type="cpu", dtype=torch.bfloat16):
        preds = model(*_images(1, 32, 48))
    assert all(p.dtype == torch.float32 and torch.isfinite(p).all() for p in preds)


def test_rejects_bad_inputs_and_names():
    model = build_model("small")
    with pytest.raises(ProjregError):
        model(torch.zeros(1, 3, 32, 32), torch.zeros(1, 3, 32, 48))
    with pytest.raises(ProjregError):
        model(torch.zeros(1, 1, 32, 32), torch.zeros(1, 1, 32, 32))
    with pytest.raises(ProjregError):
        build_model("huge")
    with pytest.raises(ProjregError):
        SSJMFlow(feature_channels=30)


def test_small_overfits_a_shifted_pair():
    torch.manual_seed(0)
    h, w, s = 48, 64, 3
    g = torch.Generator().manual_seed(0)
    blobs = F.interpolate(torch.rand(1, 3, h // 4, (w + s) // 4 + 1, generator=g), size=(h, w + s), mode="bilinear")
    tex = 255 * (0.5 * blobs + 0.5 * torch.rand(1, 3, h, w + s, generator=g))
    img0, img1 = tex[..., s : s + w], tex[..., :w]  # img1(x + s, y) = img0(x, y)
    gt = torch.zeros(1, 2, h, w)
    gt[:, 0] = s
    valid = torch.ones(1, h, w, dtype=torch.bool)
    valid[..., w - s :] = False
    model = build_model("small").train()
    opt = torch.optim.Adam(model.parameters(), lr=4e-4)
    losses = []
    for _ in range(30):
        loss, _ = sequence_loss(model(img0, img1), gt, valid)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    print(f"overfit loss {losses[0]:.2f} -> {losses[-1]:.2f}")
    assert min(losses[-5:]) < 0.4 * losses[0]
