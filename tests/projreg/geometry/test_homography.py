"""Homographies fitted to flows: robust, refusing the degenerate, and their affine stand-in."""

import numpy as np
import pytest

from projreg.geometry.homography import area_ratio, fit_affine, fit_homography, homography_flow, rescaled
from projreg.geometry.warp import compose

H_TRUE = np.array([[1.02, 0.03, 4.0], [-0.02, 0.98, -3.0], [1e-4, -5e-5, 1.0]])


def test_fit_homography_recovers_h_through_outliers():
    h, w = 120, 160
    flow = homography_flow(H_TRUE, h, w)
    rng = np.random.default_rng(1)
    bad = rng.random((h, w)) < 0.3
    flow[bad] = rng.uniform(-40, 40, (int(bad.sum()), 2))
    H, hull = fit_homography(flow, 2, 1.0)
    assert np.abs(homography_flow(H, h, w) - homography_flow(H_TRUE, h, w)).max() < 1e-3
    assert hull.mean() > 0.95  # inliers everywhere: the hull is the frame
    left = np.zeros((h, w), bool)
    left[:, : w // 4] = True
    H, hull = fit_homography(flow, 2, 1.0, left)  # fitted on the left quarter only
    assert np.abs(homography_flow(H, h, w) - homography_flow(H_TRUE, h, w)).max() < 1e-3
    assert 0.2 < hull.mean() < 0.26 and not hull[:, w // 4 + 2 :].any()
    assert fit_homography(flow, 2, 1.0, left, min_hull=0.3) is None


def test_fit_homography_refuses_flows_through_infinity():
    h, w = 50, 60
    H = np.array([[1, 0, 0], [0, 1, 0], [-0.05, 0, 1.0]])  # the line x = 20 goes to infinity
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    q = np.stack([x, y, np.ones_like(x)], -1) @ H.T
    flow = q[..., :2] / np.where(np.abs(q[..., 2:]) < 1e-6, 1e-6, q[..., 2:]) - np.stack([x, y], -1)
    assert fit_homography(flow.astype(np.float32), 1, 0.5) is None


def test_area_ratio_flags_homographies_that_explode_or_mirror():
    h, w = 100, 200
    assert area_ratio(H_TRUE, h, w) == pytest.approx(1.04, abs=0.04)  # a mild projective view
    steep = np.array([[1, 0, 0], [0, 1, 0], [0.004, 0, 1.0]])  # denominator 1 .. 1.8 across the frame
    assert area_ratio(steep, h, w) == pytest.approx(1.796**3, rel=1e-3)
    assert area_ratio(np.diag([-1.0, 1, 1]), h, w) == np.inf  # a mirror
    flow = homography_flow(steep, h, w)
    assert fit_homography(flow, 2, 1.0, max_area_ratio=5.0) is None
    assert fit_homography(flow, 2, 1.0, max_area_ratio=6.0) is not None


def test_fit_affine_recovers_an_affine_flow_as_a_3x3_matrix():
    A = np.array([[1.1, 0.05, 7.0], [-0.03, 0.95, -4.0], [0.0, 0.0, 1.0]])
    flow = homography_flow(A, 96, 128)
    fit = fit_affine(flow, 8, 1.0)
    assert fit is not None and fit[1].mean() > 0.8
    np.testing.assert_allclose(fit[0], A, atol=1e-4)
    mirror = homography_flow(np.array([[-1.0, 0.0, 127.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), 96, 128)
    assert fit_affine(mirror, 8, 1.0) is None  # a camera cannot see the image mirrored


def test_compose_chains_a_residual_and_a_base():
    h, w = 40, 50
    base = homography_flow(H_TRUE, h, w)
    r = np.zeros((h, w, 2), np.float32)
    r[...] = (2.0, -1.0)  # integer shift: remap of the base is exact at interior pixels
    out = compose(base, r)
    y, x = np.mgrid[0:h, 0:w]
    expected = r[5:-5, 5:-5] + base[y[5:-5, 5:-5] - 1, x[5:-5, 5:-5] + 2]
    np.testing.assert_allclose(out[5:-5, 5:-5], expected, atol=1e-5)


def test_homography_flow_is_the_projective_map_minus_the_pixel():
    h, w = 30, 40
    flow = homography_flow(H_TRUE, h, w)
    for x, y in ((0, 0), (39, 0), (17, 23), (39, 29)):
        q = H_TRUE @ [x, y, 1.0]
        np.testing.assert_allclose(flow[y, x], q[:2] / q[2] - [x, y], atol=1e-4)


def test_a_homography_rescaled_maps_the_resized_frames_pixel_centres():
    """A map between two 600 x 800 frames, as one between the same frames at 384 x 512: the shrunk flow
    of its flow (pixel centres kept, the vectors scaled); and back again."""
    from projreg.geometry.frames import resize_flow

    H = np.array([[0.93, 0.05, 12.0], [-0.03, 0.96, 8.0], [2e-4, -1e-4, 1.0]])
    small = rescaled(H, (600, 800), (384, 512))
    expected = resize_flow(homography_flow(H, 600, 800), (384, 512))
    inner = (slice(2, -2), slice(2, -2))  # the resized flow's border averages fewer pixels
    assert np.abs(homography_flow(small, 384, 512)[inner] - expected[inner]).max() < 0.01
    assert np.allclose(rescaled(small, (384, 512), (600, 800)), H)
