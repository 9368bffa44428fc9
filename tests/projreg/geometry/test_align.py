"""Direct photometric alignment against warps written here: a homography bent by a smooth surface, with
a camera response, noise, and a start several pixels off."""

import cv2
import numpy as np
import pytest

from projreg.geometry.align import Stopped, align, pyramid, spline_field
from projreg.geometry.homography import homography_flow
from projreg.geometry.images import normalize_contrast, texture_weight
from projreg.geometry.warp import warp_back

H_TRUE = np.array([[0.95, 0.04, 10.0], [-0.03, 0.97, 6.0], [1e-4, -5e-5, 1.0]])


def textured(h, w, seed=0):
    """A picture with texture at several scales (blurred noise plus a few shapes)."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 2.0)
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    for _ in range(12):
        cv2.circle(img, (int(rng.integers(0, w)), int(rng.integers(0, h))), int(rng.integers(5, 30)), 255.0, 2)
    return img.astype(np.uint8)


def bent(h, w, amp):
    """The forward flow of ``H_TRUE`` followed by a smooth bump (a curved wall), projected -> captured."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    bump = amp * np.exp(-(((x - 0.6 * w) / (0.3 * w)) ** 2 + ((y - 0.4 * h) / (0.35 * h)) ** 2))
    flow = homography_flow(H_TRUE, h, w)
    flow[..., 0] += bump
    flow[..., 1] -= 0.5 * bump
    return flow


def capture(projected, flow, seed=1):
    """The captured image: ``projected`` seen through ``flow`` (inverted on the camera grid by fixed-point
    iteration), through a gamma-2.2 response, with sensor noise."""
    h, w = projected.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    src_x, src_y = x.copy(), y.copy()
    for _ in range(40):  # solve p + flow(p) = q for p at every camera pixel q
        moved = cv2.remap(flow, src_x, src_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        src_x, src_y = x - moved[..., 0], y - moved[..., 1]
    cap = cv2.remap(projected.astype(np.float32), src_x, src_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    cap = 255 * (cap / 255) ** (1 / 2.2) + np.random.default_rng(seed).normal(0, 1.5, cap.shape)
    return np.clip(cap, 0, 255).astype(np.uint8)


def run(projected, captured, start, grid=(6, 5)):
    n0, n1 = normalize_contrast(projected, 8.0), normalize_contrast(captured, 8.0)
    levels = pyramid(n0, n1, texture_weight(projected, 256.0), (4, 2, 1))
    flow = align(levels, start, grid, {4: 6, 2: 4, 1: 3}, bend=0.01, ridge=1e-4)
    return align(levels, flow, (14, 11), {1: 3}, bend=0.1, ridge=1e-4)


@pytest.mark.parametrize("amp", [0.0, 4.0])
def test_align_recovers_a_bent_homography_from_a_start_pixels_off(amp):
    h, w = 192, 256
    projected = textured(h, w)
    truth = bent(h, w, amp)
    captured = capture(projected, truth)
    start = homography_flow(H_TRUE @ np.array([[1, 0, 3.0], [0, 1, -2.5], [0, 0, 1]]), h, w)  # ~4 px off
    flow = run(projected, captured, start)
    inner = np.zeros((h, w), bool)
    inner[12:-12, 12:-12] = True  # the border sees the reflected surround
    err = np.linalg.norm(flow - truth, axis=-1)[inner]
    assert np.linalg.norm(start - truth, axis=-1)[inner].mean() > 2.0
    assert err.mean() < 0.08 and np.percentile(err, 99) < 0.3, (err.mean(), np.percentile(err, 99))
    # the images agree under the answer: the residual is noise, not structure
    seen = warp_back(captured.astype(np.float32), flow)
    ref = 255 * (projected.astype(np.float32) / 255) ** (1 / 2.2)
    assert np.abs(seen - ref)[inner].mean() < 3.0


def test_a_tolerance_stops_steps_only_once_they_no_longer_move_the_answer():
    """With ``tolerance`` a level stops once a step moves no control value that far: from a start pixels
    off it still closes the distance (unlike one step a level), and ends where all the steps would have."""
    h, w = 192, 256
    projected = textured(h, w)
    truth = bent(h, w, 4.0)
    captured = capture(projected, truth)
    n0, n1 = normalize_contrast(projected, 8.0), normalize_contrast(captured, 8.0)
    levels = pyramid(n0, n1, texture_weight(projected, 256.0), (4, 2, 1))
    off = homography_flow(H_TRUE @ np.array([[1, 0, 3.0], [0, 1, -2.5], [0, 0, 1]]), h, w)
    every = align(levels, off, (6, 5), {4: 40, 2: 40, 1: 40}, 0.01, 1e-4)
    early = align(levels, off, (6, 5), {4: 40, 2: 40, 1: 40}, 0.01, 1e-4, tolerance=0.02)
    once = align(levels, off, (6, 5), {4: 1, 2: 1, 1: 1}, 0.01, 1e-4)
    inner = (slice(12, -12), slice(12, -12))
    gap = np.linalg.norm(early - every, axis=-1)[inner]
    err, err_once = (np.linalg.norm(f - truth, axis=-1)[inner].mean() for f in (early, once))
    assert gap.max() < 0.1 and err < 0.3 < err_once, (gap.max(), err, err_once)


def test_an_alignment_asked_to_stop_raises_at_its_next_step_and_otherwise_answers_as_without():
    h, w = 96, 128
    projected = textured(h, w)
    captured = capture(projected, bent(h, w, 2.0))
    levels = pyramid(projected, captured, texture_weight(projected, 256.0), (2, 1))
    start = homography_flow(H_TRUE, h, w)
    asked = []

    def stop_after(n):
        return lambda: asked.append(1) or len(asked) > n

    plain = align(levels, start, (6, 5), {2: 4, 1: 3}, 0.01, 1e-4)
    np.testing.assert_array_equal(align(levels, start, (6, 5), {2: 4, 1: 3}, 0.01, 1e-4, stop=lambda: False), plain)
    with pytest.raises(Stopped):
        align(levels, start, (6, 5), {2: 4, 1: 3}, 0.01, 1e-4, stop=stop_after(2))
    assert len(asked) == 3  # asked before each step: two taken, the third refused


def test_align_without_texture_stays_at_its_start():
    h, w = 96, 128
    flat = np.full((h, w), 120, np.uint8)
    start = homography_flow(H_TRUE, h, w)
    flow = run(flat, flat, start)
    assert np.abs(flow - start).max() < 1e-3


def test_spline_field_is_the_tensor_product_spline():
    control = np.zeros((5, 6, 2))
    control[..., 0] = 1.5  # a constant: the basis sums to one everywhere
    control[2, 3, 1] = 2.0
    field = spline_field(control, 40, 50)
    np.testing.assert_allclose(field[..., 0], 1.5, atol=1e-5)
    assert field[..., 1].max() > 0.5 and field[..., 1].min() >= -1e-6


def test_steps_bounded_on_the_texture_are_not_shortened_by_a_flat_region():
    """Content on the left half only: control values over the flat right half move freely (only the bend
    holds them), and bounding every step by the farthest control value (``max_step``) shortens the steps
    for the textured half too. Bounded by how far the textured pixels move (``on_texture``), the same few
    steps close more of the distance there."""
    h, w = 192, 256
    projected = textured(h, w)
    projected[:, w // 2 :] = 120
    truth = bent(h, w, 4.0)
    captured = capture(projected, truth)
    n0, n1 = normalize_contrast(projected, 8.0), normalize_contrast(captured, 8.0)
    levels = pyramid(n0, n1, texture_weight(projected, 256.0), (4, 2, 1))
    start = homography_flow(H_TRUE @ np.array([[1, 0, 3.0], [0, 1, -2.5], [0, 0, 1]]), h, w)
    steps = {4: 2, 2: 2, 1: 2}
    inner = np.zeros((h, w), bool)
    inner[12:-12, 12 : w // 2 - 12] = True
    err = {
        on: np.linalg.norm(align(levels, start, (6, 5), steps, 0.01, 1e-4, on_texture=on) - truth, axis=-1)[inner]
        for on in (False, True)
    }
    assert err[True].mean() < 0.6 * err[False].mean(), (err[True].mean(), err[False].mean())


def test_narrow_last_steps_let_go_of_occluders_a_wide_cauchy_let_pull():
    """Bright discs over the captured image (edges the projected image does not have): the alignment with
    a wide Cauchy (2.385 standard deviations) lets their edges pull the surface beside them; its last three
    fine steps at one standard deviation (``last``, as ``balanced`` aligns) end as close to the truth there
    as narrow steps throughout, whose slower convergence the wide ones were for."""
    h, w = 192, 256
    projected = textured(h, w)
    truth = bent(h, w, 4.0)
    captured = capture(projected, truth)
    rng = np.random.default_rng(3)
    discs = np.zeros((h, w), np.uint8)
    for _ in range(8):
        centre = (int(rng.integers(20, w - 20)), int(rng.integers(20, h - 20)))
        cv2.circle(discs, centre, int(rng.integers(10, 22)), 1, -1)
    captured[discs > 0] = 230
    start = homography_flow(H_TRUE @ np.array([[1, 0, 1.5], [0, 1, -1.0], [0, 0, 1]]), h, w)
    levels = pyramid(
        normalize_contrast(projected, 8.0),
        normalize_contrast(captured, 8.0),
        texture_weight(projected, 256.0),
        (4, 2, 1),
    )
    seen = np.zeros((h, w), bool)
    seen[12:-12, 12:-12] = True  # the border sees the reflected surround
    seen &= discs == 0

    def tail(cauchy, fine_steps, last=(0, 1.0)):
        flow = align(levels, start, (6, 5), {4: 6, 2: 4, 1: 1}, 0.01, 1e-4, tolerance=0.02, cauchy=cauchy)
        flow = align(levels, flow, (14, 11), {1: fine_steps}, 0.1, 1e-4, tolerance=0.02, cauchy=cauchy, last=last)
        return float(np.percentile(np.linalg.norm(flow - truth, axis=-1)[seen], 99))

    wide, graduated, narrow = tail(2.385, 6), tail(2.385, 6, (3, 1.0)), tail(1.0, 6)
    assert graduated < 0.8 * wide, (graduated, wide)
    assert graduated < 1.1 * narrow, (graduated, narrow)
