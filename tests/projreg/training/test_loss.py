"""sequence_loss: known values, gamma weighting, invalid pixels ignored, empty batches safe."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from projreg import ProjregError
from projreg.training.loss import sequence_loss


def _tiny():
    # B=1, H=1, W=3; pixel 2 is invalid
    gt = torch.tensor([[[[1.0, 2.0, 50.0]], [[0.0, -1.0, 50.0]]]])
    valid = torch.tensor([[[True, True, False]]])
    p0 = torch.tensor([[[[2.0, 2.0, 0.0]], [[0.0, 1.0, 0.0]]]])  # |err| = 1, 0 | 0, 2 -> sum 3
    p1 = torch.tensor([[[[1.0, 2.5, 9.0]], [[0.0, -1.0, 9.0]]]])  # |err| = 0, 0.5 | 0, 0 -> sum 0.5
    return [p0, p1], gt, valid


def test_known_value():
    preds, gt, valid = _tiny()
    loss, metrics = sequence_loss(preds, gt, valid, gamma=0.8)
    # mean per component over 2 valid pixels (4 components): 0.8 * 3/4 + 1.0 * 0.5/4
    assert loss.item() == pytest.approx(0.8 * 0.75 + 0.125)
    assert metrics["loss"] == pytest.approx(loss.item())
    assert metrics["epe"] == pytest.approx(0.25)  # last prediction: EPE 0 and 0.5
    assert metrics["px1"] == 0.0 and metrics["n_valid"] == 2.0


def test_later_predictions_weigh_more():
    preds, gt, valid = _tiny()
    bad_last, _ = sequence_loss(preds[::-1], gt, valid)
    good_last, _ = sequence_loss(preds, gt, valid)
    assert good_last < bad_last


def test_invalid_pixels_do_not_contribute_even_nan():
    preds, gt, valid = _tiny()
    preds = [p.clone().requires_grad_(True) for p in preds]
    ref, _ = sequence_loss(preds, gt, valid)
    gt2 = gt.clone()
    gt2[..., 2] = float("nan")
    preds2 = [p.detach().clone() for p in preds]
    preds2[0][..., 2] = float("inf")
    preds2[1][..., 2] = -1e9
    preds2 = [p.requires_grad_(True) for p in preds2]
    loss2, metrics2 = sequence_loss(preds2, gt2, valid)
    assert loss2.item() == ref.item()
    assert math.isfinite(metrics2["epe"])
    loss2.backward()
    for p in preds2:
        assert torch.isfinite(p.grad).all()
        assert p.grad[..., 2].abs().max() == 0.0


def test_no_valid_pixel_gives_zero_loss_with_grad():
    preds, gt, _ = _tiny()
    pred = preds[0].clone().requires_grad_(True)
    loss, metrics = sequence_loss([pred], gt, torch.zeros(1, 1, 3, dtype=torch.bool))
    assert loss.item() == 0.0 and loss.requires_grad
    loss.backward()
    assert torch.equal(pred.grad, torch.zeros_like(pred))
    assert math.isnan(metrics["epe"]) and metrics["n_valid"] == 0.0


def test_max_flow_excludes_large_ground_truth():
    preds, gt, valid = _tiny()
    gt = gt.clone()
    gt[0, 0, 0, 0] = 500.0  # pixel 0 now has a huge flow and a huge error
    loss, metrics = sequence_loss(preds[-1:], gt, valid, max_flow=400.0)
    assert loss.item() == pytest.approx(0.5 / 2)  # only pixel 1 counts: 0.5 / (2 components)
    assert metrics["n_valid"] == 1.0


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 3), st.integers(1, 4), st.integers(1, 4), st.integers(1, 3), st.integers(0, 10_000))
def test_matches_numpy_reference(b, h, w, n, seed):
    rng = np.random.default_rng(seed)
    gt = rng.normal(scale=5, size=(b, 2, h, w))
    valid = rng.random((b, h, w)) < 0.6
    preds = [rng.normal(scale=5, size=(b, 2, h, w)) for _ in range(n)]
    loss, _ = sequence_loss([torch.from_numpy(p) for p in preds], torch.from_numpy(gt), torch.from_numpy(valid))
    m = valid[:, None].repeat(2, axis=1)
    expected = sum(0.9 ** (n - 1 - i) * (np.abs(p - gt)[m].sum() / max(m.sum(), 1)) for i, p in enumerate(preds))
    assert loss.item() == pytest.approx(expected, rel=1e-10, abs=1e-12)


def test_rejects_bad_shapes():
    preds, gt, valid = _tiny()
    with pytest.raises(ProjregError):
        sequence_loss([], gt, valid)
    with pytest.raises(ProjregError):
        sequence_loss([preds[0][..., :2]], gt, valid)
    with pytest.raises(ProjregError):
        sequence_loss(preds, gt, valid[..., :2])
