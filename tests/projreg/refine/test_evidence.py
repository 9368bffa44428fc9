"""What the images say beyond the score: outside the support, alignment, periodicity."""

import cv2
import numpy as np
import pytest

from projreg.geometry.images import near, normalize_contrast, texture_weight
from projreg.geometry.warp import warp_back
from projreg.refine.config import RefineConfig
from projreg.refine.evidence import alignment_score, bound_outside, repeating


def test_bound_outside_and_near():
    mask = np.zeros((5, 9), bool)
    mask[2, 1] = True
    np.testing.assert_array_equal(near(mask, 2.0)[2], [1, 1, 1, 1, 0, 0, 0, 0, 0])
    flow = np.zeros((5, 9, 2), np.float32)
    flow[..., 0] = 100.0
    prior = np.full_like(flow, 1.0)
    out = bound_outside(flow, prior, mask, 5.0)
    assert out[2, 1].tolist() == [100.0, 0.0]
    np.testing.assert_allclose(np.linalg.norm(out[0, 0] - prior[0, 0]), 5.0, rtol=1e-6)


def test_warp_back_and_alignment_score():
    rng = np.random.default_rng(2)
    gray0 = cv2.GaussianBlur(rng.integers(0, 256, (64, 80), dtype=np.uint8), (0, 0), 1.5)
    shift = np.zeros((64, 80, 2), np.float32)
    shift[...] = (3, 2)
    gray1 = np.roll(gray0, (2, 3), axis=(0, 1))  # gray1[p + (3, 2)] = gray0[p]
    np.testing.assert_array_equal(warp_back(gray1, shift)[5:-5, 5:-5], gray0[5:-5, 5:-5])
    # invariant to gain and offset; a wrong flow scores far lower
    dim = (0.5 * gray1 + 60).astype(np.uint8)
    assert alignment_score(gray0, dim, shift) > 0.95
    assert alignment_score(gray0, dim, np.zeros_like(shift)) < 0.5
    # weighted by texture: a flat half of the frame neither helps nor hurts
    half0, half1 = gray0.copy(), dim.copy()
    half0[:, 40:], half1[:, 40:] = 100, 100
    weight = texture_weight(half0, 256.0)
    assert weight[:, 52:].max() < 0.05 and weight[:, 5:30].min() > 0.5
    weighted = alignment_score(half0, half1, shift, weight=weight)
    assert weighted > 0.8 and weighted > alignment_score(half0, half1, shift) + 0.2


def test_a_photographed_brick_wall_is_not_called_repeating_by_the_coarse_windows():
    """Bricks repeat roughly (0.83-0.91 in the 128 px window) and were registered right; a digital motif
    repeats exactly (0.98-1.00). The coarse windows' stricter peak keeps the bricks claimable."""
    data = pytest.importorskip("skimage.data")
    brick = cv2.resize(data.brick(), (512, 384), interpolation=cv2.INTER_AREA)
    gray = normalize_contrast(brick, RefineConfig().images.contrast_sigma)
    assert repeating(gray).mean() < 0.05
    assert repeating(gray, coarse_peak=0.85).mean() > 0.2  # at the fine window's peak a third of it repeats
