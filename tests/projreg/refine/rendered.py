"""Pairs rendered in the tests with their exact truth (projsynth's and a bend written here), and
network-like flows for them."""

import cv2
import numpy as np


def epe(flow, s):
    """Mean end-point error of ``flow`` on sample ``s``'s valid pixels."""
    return float(np.linalg.norm(flow - s["flow"], axis=-1)[s["valid"]].mean())


def coarse(s, rng):
    """A flow like an undertrained network's: the truth plus a smooth 2-3 px bias and 20% wild outliers."""
    h, w = s["valid"].shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    flow = np.where(s["valid"][..., None], s["flow"], np.nan_to_num(s["flow"]))
    bias = np.stack([2 + np.sin(x / 23.0), -1.5 + np.cos(y / 17.0)], axis=-1)
    wild = rng.random((h, w)) < 0.2
    flow = flow + bias
    flow[wild] = rng.uniform(-30, 30, (int(wild.sum()), 2))
    return flow.astype(np.float32)


# Pairs whose truth projsynth did not make: a smooth bend (a homography then a sinusoidal warp),
# rendered with cv2.remap, a camera response (gamma 1/2.2), a dark surround and sensor noise.
BEND_H = np.array([[0.93, 0.05, 12.0], [-0.03, 0.96, 8.0], [2e-4, -1e-4, 1.0]])


def bent_pair(picture, amp=3.0, period=150.0, seed=0, wall=None, homography=BEND_H):
    """``(projected, captured, flow, valid)``: forward map ``q = H p`` (``homography``, the projector's
    pose) then ``q + amp * sin(2 pi q / period)`` (the sheet's bend, fixed in the camera frame);
    ``wall``: the wall's reflectance in the camera frame, float ``(H, W)`` (None: uniform)."""
    h, w = picture.shape[:2]
    k = 2 * np.pi / period
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    p = np.stack([x, y], axis=-1)

    def bend(q):
        return q + amp * np.stack([np.sin(k * q[..., 1]), np.sin(k * q[..., 0])], axis=-1)

    hp = np.concatenate([p, np.ones_like(x)[..., None]], axis=-1) @ homography.T
    fwd = bend(hp[..., :2] / hp[..., 2:])
    q = p.copy()  # invert the bend at every camera pixel (a contraction: amp * k < 1)
    for _ in range(50):
        q = p - (bend(q) - q)
    src = np.concatenate([q, np.ones_like(x)[..., None]], axis=-1) @ np.linalg.inv(homography).T
    src = (src[..., :2] / src[..., 2:]).astype(np.float32)
    lit = (src[..., 0] >= 0) & (src[..., 0] <= w - 1) & (src[..., 1] >= 0) & (src[..., 1] <= h - 1)
    cap = cv2.remap(picture.astype(np.float32), src[..., 0], src[..., 1], cv2.INTER_LINEAR)
    cap = np.where(lit[..., None], cap, 6.0) * (1.0 if wall is None else wall[..., None])
    cap = 255 * (cap / 255) ** (1 / 2.2)
    cap = cap + np.random.default_rng(seed).normal(0, 1.5, cap.shape)
    valid = (fwd[..., 0] >= 0) & (fwd[..., 0] <= w - 1) & (fwd[..., 1] >= 0) & (fwd[..., 1] <= h - 1)
    return picture, np.clip(cap, 0, 255).astype(np.uint8), (fwd - p).astype(np.float32), valid


def network_like(flow, textured, rng):
    """What the network gives on such a pair: near the truth on the content, 12 px off beyond it."""
    out = flow + rng.normal(0, 1.5, flow.shape).astype(np.float32)
    out[~textured] += np.float32([9.0, -8.0])
    return out
