"""Structured-light decoding against truth projsynth did not make: an analytic rig written here.

The rig: camera pixel ``q`` sees projector position ``G(q)`` = a homography plus a smooth bend; the
projector has gamma 2.2; the surface an albedo texture; the camera ambient light, defocus, pixel-area
integration (2x supersampling), a 1/2.2 response, noise and 8-bit quantisation; its frame is 1.25x
the projector's. The true forward map is ``G``'s inverse, found here by Newton's method.
"""

import cv2
import numpy as np
import pytest

from projsynth.structured.decode import decode
from projsynth.structured.patterns import dot_centres, make_set

H_CAM_FROM_PROJ = np.array([[1.18, 0.06, 22.0], [-0.04, 1.21, 14.0], [2.0e-4, 1.0e-4, 1.0]])


def proj_from_cam(qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``G``: the projector position a camera pixel sees (inverse homography, then a smooth bend)."""
    Hi = np.linalg.inv(H_CAM_FROM_PROJ)
    w = Hi[2, 0] * qx + Hi[2, 1] * qy + Hi[2, 2]
    px = (Hi[0, 0] * qx + Hi[0, 1] * qy + Hi[0, 2]) / w
    py = (Hi[1, 0] * qx + Hi[1, 1] * qy + Hi[1, 2]) / w
    return px + 2.5 * np.sin(qy / 37.0), py + 1.8 * np.sin(qx / 53.0 + 0.4)


def true_forward(size: tuple[int, int]) -> np.ndarray:
    """``(H, W, 2)``: the camera position of every projector pixel (Newton on ``G``, to 1e-9 px)."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    p = np.stack([xs, ys, np.ones_like(xs)], -1) @ H_CAM_FROM_PROJ.T
    qx, qy = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
    e = 1e-4
    for _ in range(30):
        gx, gy = proj_from_cam(qx, qy)
        rx, ry = gx - xs, gy - ys
        if max(np.abs(rx).max(), np.abs(ry).max()) < 1e-9:
            break
        ax, ay = proj_from_cam(qx + e, qy)
        bx, by = proj_from_cam(qx, qy + e)
        j11, j21, j12, j22 = (ax - gx) / e, (ay - gy) / e, (bx - gx) / e, (by - gy) / e
        det = j11 * j22 - j12 * j21
        qx, qy = qx - (j22 * rx - j12 * ry) / det, qy - (-j21 * rx + j11 * ry) / det
    return np.stack([qx, qy], -1)


def photograph(
    patterns: list[np.ndarray],
    camera: tuple[int, int],
    seed: int,
    *,
    ambient: float = 0.08,
    gain: float = 0.9,
    noise: float = 1.5,
) -> np.ndarray:
    """The analytic rig's photos ``(N, Hc, Wc)`` float32 in [0, 1] of uint8 projector ``patterns``."""
    rng = np.random.default_rng(seed)
    hc, wc = camera
    s = 2  # supersampling: a camera pixel integrates its area
    ys, xs = np.mgrid[0 : hc * s, 0 : wc * s].astype(np.float64)
    px, py = proj_from_cam((xs + 0.5) / s - 0.5, (ys + 0.5) / s - 0.5)
    h, w = patterns[0].shape
    lit = (px >= -0.5) & (px <= w - 0.5) & (py >= -0.5) & (py <= h - 0.5)
    coarse = rng.uniform(0.35, 1.0, (12, 16)).astype(np.float32)
    albedo = cv2.resize(coarse, (wc * s, hc * s), interpolation=cv2.INTER_CUBIC).clip(0.25, 1.0)
    photos = []
    for pat in patterns:
        light = (pat.astype(np.float32) / 255) ** 2.2  # projector gamma
        seen = (
            cv2.remap(
                light, px.astype(np.float32), py.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
            * lit
        )
        lin = gain * albedo * (ambient + 0.85 * seen)
        lin = cv2.GaussianBlur(lin, (0, 0), 1.2)  # defocus, in the supersampled frame
        lin = cv2.resize(lin, (wc, hc), interpolation=cv2.INTER_AREA)
        out = 255 * np.clip(lin, 0, 1) ** (1 / 2.2) + rng.normal(0, noise, lin.shape)
        photos.append(np.clip(np.rint(out), 0, 255).astype(np.float32) / 255)
    return np.stack(photos)


def truth_valid(truth: np.ndarray, camera: tuple[int, int], margin: float = 1.0) -> np.ndarray:
    hc, wc = camera
    return (
        (truth[..., 0] >= margin)
        & (truth[..., 0] <= wc - 1 - margin)
        & (truth[..., 1] >= margin)
        & (truth[..., 1] <= hc - 1 - margin)
    )


@pytest.fixture(scope="module")
def graycode_case():
    size, camera = (120, 160), (150, 200)
    patterns = make_set("graycode", size)
    photos = photograph(patterns.images(), camera, seed=1)
    return patterns, photos, true_forward(size), camera


def test_graycode_is_subpixel_on_an_analytic_rig(graycode_case):
    patterns, photos, truth, camera = graycode_case
    result = decode(patterns, photos)
    ys, xs = np.mgrid[0 : patterns.size[0], 0 : patterns.size[1]]
    found = result.flow + np.stack([xs, ys], -1)
    inside = truth_valid(truth, camera)
    err = np.hypot(*(found - truth)[result.valid].T)
    coverage = (result.valid & inside).sum() / inside.sum()
    assert coverage >= 0.95, coverage
    assert np.median(err) <= 0.05, np.median(err)
    assert np.percentile(err, 95) <= 0.3, np.percentile(err, 95)
    outside = result.valid & ~truth_valid(truth, camera, margin=-0.5)  # truly outside the camera frame
    assert outside.sum() == 0
    assert np.all(result.flow[~result.valid] == 0)


def test_graycode_survives_strong_ambient_light_and_saturation(graycode_case):
    patterns, _, truth, camera = graycode_case
    washed = photograph(patterns.images(), camera, seed=2, ambient=1.2, gain=0.45)  # low contrast
    bright = photograph(patterns.images(), camera, seed=3, gain=1.6)  # white saturates on bright albedo
    assert (bright >= 0.999).mean() > 0.05
    ys, xs = np.mgrid[0 : patterns.size[0], 0 : patterns.size[1]]
    for photos in (washed, bright):
        result = decode(patterns, photos)
        err = np.hypot(*(result.flow + np.stack([xs, ys], -1) - truth)[result.valid].T)
        assert result.valid.sum() / truth_valid(truth, camera).sum() >= 0.8
        assert np.median(err) <= 0.1 and err.max() < 2.0, (np.median(err), err.max())


def test_dots_are_all_found_and_none_is_wrong():
    size, camera = (240, 320), (300, 400)
    patterns = make_set("dots", size)
    assert len(patterns.names) == 11
    photos = photograph(patterns.images(), camera, seed=4)
    result = decode(patterns, photos)
    truth = true_forward(size)
    centres = dot_centres(patterns)
    r = patterns.params["radius"] + 2.5  # a dot fully inside the frame, blur included
    hc, wc = camera
    inside = [np.all(truth_valid(truth[max(y - 5, 0) : y + 6, max(x - 5, 0) : x + 6], camera, r)) for x, y in centres]
    decoded = result.valid[centres[:, 1], centres[:, 0]]
    assert decoded[inside].all(), int((~decoded[inside]).sum())
    assert result.valid.sum() == decoded.sum()  # nothing but dot centres
    found = result.flow[centres[:, 1], centres[:, 0]] + centres
    err = np.hypot(*(found - truth[centres[:, 1], centres[:, 0]])[decoded].T)
    assert err.mean() <= 0.15 and err.max() < 1.0, (err.mean(), err.max())
