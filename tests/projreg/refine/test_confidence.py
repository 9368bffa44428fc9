"""The per-pixel confidence: pass marks spread over two neighbourhoods, nothing far from texture."""

import cv2
import numpy as np

from projreg.prediction import CONFIDENT
from projreg.refine.confidence import eigen_ratio, neighbourhood, pinned, pixel_confidence
from projreg.refine.config import ConfidenceConfig


def _bands(gap: int, h: int = 64, w: int = 400, band: int = 60) -> np.ndarray:
    """Texture weight 1 on two vertical bands ``band`` px wide, ``gap`` px apart, 0 elsewhere."""
    texture = np.zeros((h, w), np.float32)
    texture[:, :band] = 1.0
    texture[:, band + gap : 2 * band + gap] = 1.0
    return texture


def _confidence(texture, fail=None, radius=10.0):
    """Every check passed (ncc 1, residual 0, spread 0) except on the bool mask ``fail`` (ncc 0)."""
    ncc = np.ones_like(texture) if fail is None else np.where(fail, 0.0, 1.0).astype(np.float32)
    zero = np.zeros_like(texture)
    return pixel_confidence(texture, ncc, zero, zero, radius, ConfidenceConfig())


def test_a_flat_gap_between_verified_texture_is_claimed_by_the_coarse_neighbourhood():
    texture = _bands(gap=50)
    middle = (slice(None), slice(60 + 20, 60 + 30))  # 20-30 px (2-3 fine sigmas) from either band
    passed = np.ones_like(texture)
    fine = neighbourhood(texture, passed, 10.0, 0.05)
    assert fine[middle].max() < CONFIDENT  # the fine scale alone leaves the gap out (the rule before)
    assert _confidence(texture)[middle].min() >= CONFIDENT


def test_far_from_texture_or_beside_failed_texture_nothing_is_claimed():
    texture = _bands(gap=70)
    conf = _confidence(texture)
    assert conf[:, 300:].max() == 0.0  # 110+ px beyond the last band: no texture in either window
    assert _confidence(_bands(gap=70))[:, 60 + 30 : 60 + 40].max() < CONFIDENT  # a gap too wide for both
    failed = _confidence(texture, fail=texture > 0)  # the same texture, every check failed
    assert failed.max() == 0.0
    left_fails = np.zeros(texture.shape, bool)
    left_fails[:, :60] = True
    half = _confidence(texture, fail=left_fails)
    assert half[:, :40].max() < CONFIDENT and half[:, 140:180].min() >= CONFIDENT


def test_a_wide_neighbourhood_on_the_shrunk_grid_matches_the_full_size_one():
    """From a sigma of 12 px the averages are taken on a shrunk grid; written out at full size here."""
    rng = np.random.default_rng(5)
    h, w = 240, 360
    texture = (cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 4) > 0.5).astype(np.float32)
    passed = np.zeros((h, w), np.float32)
    passed[:, : w // 2] = 1.0  # the checks pass on the left half only

    def full_size(sigma):
        density = cv2.GaussianBlur(texture, (0, 0), sigma)
        agree = cv2.GaussianBlur(texture * passed, (0, 0), sigma) / np.maximum(density, 1e-6)
        return agree * np.clip((density - 0.1) / 0.1, 0, 1)

    for sigma in (15.4, 30.7, 96.0):  # the default's fine and coarse neighbourhoods at 512 px; 16 times shrunk
        shrunk = neighbourhood(texture, passed, sigma, 0.1)
        assert shrunk.shape == (h, w) and np.abs(shrunk - full_size(sigma)).max() < 0.025, sigma
    np.testing.assert_allclose(neighbourhood(texture, passed, 11.0, 0.1), full_size(11.0), atol=1e-5)  # not shrunk


def _pin(image: np.ndarray, flow: np.ndarray, radius: float = 12.0) -> np.ndarray:
    """:func:`pinned` of a gray ``image`` whose every textured pixel passed the checks, under ``flow``."""
    gray = image.astype(np.float32)
    gx, gy = cv2.Scharr(gray, cv2.CV_32F, 1, 0), cv2.Scharr(gray, cv2.CV_32F, 0, 1)
    ratio = eigen_ratio([gx * gx, gx * gy, gy * gy], 7.0, 3.5)
    texture = np.minimum(cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), 3) / 1e5, 1.0)
    return pinned(ratio, texture, np.ones_like(texture), flow, radius, ConfidenceConfig())


def test_a_curve_alone_pins_nothing_where_the_surface_bends_and_a_corner_does():
    """Circles fix no position along themselves within a check window; on a plane the span test speaks
    for them, but where the flow bends their pixels slide along them, and only windows that fix a
    position alone (the crossings of a grid) pin the answer."""
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    circles = np.zeros((h, w), np.uint8)
    for r in (40, 70, 100):
        cv2.circle(circles, (160, 120), r, 255, 2, cv2.LINE_AA)
    grid = np.zeros((h, w), np.uint8)
    grid[::24, :] = 255
    grid[:, ::24] = 255
    grid = cv2.GaussianBlur(grid, (0, 0), 1.0)
    bumps = np.dstack([4 * np.sin(xx / 25) * np.sin(yy / 25), 4 * np.cos(xx / 25) * np.sin(yy / 30)])
    plane = np.dstack([0.05 * xx + 3, -0.02 * yy + 1])
    on = cv2.dilate(circles, np.ones((3, 3), np.uint8)) > 0
    assert _pin(circles, bumps)[on].mean() < 0.1
    assert _pin(circles, plane)[on].min() == 1.0
    assert _pin(grid, bumps)[grid > 64].min() == 1.0


def test_where_the_surface_bends_the_claim_reaches_less_far_into_a_flat_gap():
    """The coarse neighbourhood carries a verdict across a flat gap that the surface model interpolates;
    where the answer bends within a radius or two, that interpolation is a guess: the claim reaches into
    the flat half of the frame only as far as the fine neighbourhood carries it (on a plane, farther)."""
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    grid = np.zeros((h, w), np.uint8)
    grid[::24, :160] = 255
    grid[:, :160:24] = 255
    grid = cv2.GaussianBlur(grid, (0, 0), 1.0)
    gray = grid.astype(np.float32)
    gx, gy = cv2.Scharr(gray, cv2.CV_32F, 1, 0), cv2.Scharr(gray, cv2.CV_32F, 0, 1)
    texture = np.minimum(cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), 3) / 1e5, 1.0)
    zero = np.zeros_like(texture)
    conf = pixel_confidence(texture, np.ones_like(texture), zero, zero, 12.0, ConfidenceConfig())
    bumps = np.dstack([4 * np.sin(xx / 25) * np.sin(yy / 25), 4 * np.cos(xx / 25) * np.sin(yy / 30)])
    plane = np.dstack([0.05 * xx + 3, -0.02 * yy + 1])
    bent, flat = (conf * _pin(grid, flow) >= CONFIDENT for flow in (bumps, plane))
    assert bent[:, :150].all() and flat[:, :150].all()  # the grid: its crossings pin it
    reach_bent, reach_flat = (int(np.flatnonzero(c[120]).max()) for c in (bent, flat))
    assert 160 < reach_bent <= reach_flat - 8  # past the texture, less far than on a plane
