"""Homographies: fitted to a flow (robustly, on a grid of its vectors), estimated from SIFT matches,
checked for a proper frame, and densified into a flow.

Convention: ``H`` maps projected pixels to captured pixels (3 x 3, pixel centres at integers); flows
are float32 ``(H, W, 2)``, forward, projected -> captured.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from projsynth.utils.jit import jit


def proper_homography(H: np.ndarray, height: int, width: int) -> bool:
    """Whether ``H`` keeps the whole ``height x width`` frame on one side of the line at infinity."""
    # The projective denominator is affine in (x, y): its sign over the frame is fixed by the corners.
    corners = np.array([[0, 0, 1], [width - 1, 0, 1], [0, height - 1, 1], [width - 1, height - 1, 1]], np.float64)
    den = corners @ np.asarray(H, np.float64)[2]
    return bool(np.all(den > 1e-8) or np.all(den < -1e-8))


def homography_flow(H: np.ndarray, height: int, width: int) -> np.ndarray:
    """Dense flow ``H(p) - p`` on a ``height x width`` grid, ``H`` mapping projected to captured pixels.

    Returns:
        float32 ``(height, width, 2)``, forward, projected -> captured, pixels (computed in float64).
    """
    return _homography_flow(np.asarray(H, np.float64), height, width)


@jit
def _homography_flow(H, height, width):  # pragma: no cover - numba
    flow = np.empty((height, width, 2), np.float32)
    for y in range(height):
        for x in range(width):
            den = H[2, 0] * x + (H[2, 1] * y + H[2, 2])
            flow[y, x, 0] = (H[0, 0] * x + (H[0, 1] * y + H[0, 2])) / den - x
            flow[y, x, 1] = (H[1, 0] * x + (H[1, 1] * y + H[1, 2])) / den - y
    return flow


def rescaled(H: np.ndarray, shape: tuple[int, ...], to: tuple[int, ...]) -> np.ndarray:
    """A homography between frames of ``shape[:2]`` (both sides) as one between the same frames resized to
    ``to[:2]`` (pixel centres kept: ``x' = (x + 0.5) w' / w - 0.5``)."""
    (h, w), (h2, w2) = shape[:2], to[:2]
    S = np.array([[w2 / w, 0, 0.5 * w2 / w - 0.5], [0, h2 / h, 0.5 * h2 / h - 0.5], [0, 0, 1]])  # shape -> to
    return S @ np.asarray(H, np.float64) @ np.linalg.inv(S)


def fit_step(h: int, w: int, points: int) -> int:
    """Grid step (>= 1 px) that leaves about ``points`` correspondences on an ``h x w`` frame."""
    return max(1, math.ceil(math.sqrt(h * w / points)))


Fit = tuple[np.ndarray, np.ndarray] | None  # (3 x 3 matrix, bool (H, W) hull of its inliers), or None


def fit_homography(
    flow: np.ndarray,
    step: int,
    threshold: float,
    mask: np.ndarray | None = None,
    max_area_ratio: float = math.inf,
    min_hull: float = 0.0,
) -> Fit:
    """Robust homography (projected -> captured pixels) of a flow's correspondences on a ``step`` grid.

    MAGSAC++ with ``threshold`` px, OpenCV's RNG seeded first so the result is reproducible, on the
    grid points where ``mask`` (bool ``(H, W)``, None: all) is true.

    Returns:
        ``(H, hull)``: the 3 x 3 matrix and the bool ``(H, W)`` convex hull of its inliers (the region
        the fit interpolates; outside it, it extrapolates). None when no model is found, when it
        sends part of the frame through infinity (``proper_homography``), when it is badly
        conditioned (its local area scale varies more than ``max_area_ratio`` times over the frame,
        or flips orientation: ``area_ratio``), or when the hull covers less than ``min_hull`` of it.
    """
    h, w = flow.shape[:2]
    src, dst = _grid_matches(flow, step, mask)
    if len(src) < 8:
        return None
    cv2.setRNGSeed(0)
    H, inl = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, threshold, maxIters=2000, confidence=0.999)
    if H is None or inl is None or inl.sum() < 8 or not proper_homography(H, h, w):
        return None
    if not area_ratio(H, h, w) <= max_area_ratio:
        return None
    return _with_hull(H, src[inl.ravel() > 0], h, w, min_hull)


def fit_affine(flow: np.ndarray, step: int, threshold: float, min_hull: float = 0.0) -> Fit:
    """:func:`fit_homography` with an affine model (returned as a 3 x 3 matrix): the start from a flow
    whose homography is refused as badly conditioned, e.g. under strong lens distortion, where the
    best homography over the frame bends too much. An affine map's area scale is the same everywhere,
    so it cannot be ill conditioned that way; it only starts a refinement that measures the rest."""
    h, w = flow.shape[:2]
    src, dst = _grid_matches(flow, step, None)
    if len(src) < 8:
        return None
    cv2.setRNGSeed(0)
    A, inl = cv2.estimateAffine2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=threshold, maxIters=2000)
    if A is None or inl is None or inl.sum() < 8 or np.linalg.det(A[:, :2]) <= 0:
        return None
    return _with_hull(np.vstack([A, [0.0, 0.0, 1.0]]), src[inl.ravel() > 0], h, w, min_hull)


def _grid_matches(flow: np.ndarray, step: int, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(src, dst)`` float32 ``[N, 2]``: the ``step`` grid's projected pixels where the flow is finite
    (and ``mask``, when given, is true) and where the flow sends them."""
    h, w = flow.shape[:2]
    y, x = np.mgrid[0:h:step, 0:w:step].astype(np.float32)  # [h', w'] each
    src = np.stack([x, y], axis=-1).reshape(-1, 2)  # [N, 2]
    dst = src + flow[::step, ::step].reshape(-1, 2)
    keep = np.isfinite(dst).all(axis=1)
    if mask is not None:
        keep &= mask[::step, ::step].reshape(-1)
    return src[keep], dst[keep]


def _with_hull(H: np.ndarray, inliers: np.ndarray, h: int, w: int, min_hull: float) -> Fit:
    """``(H, hull)`` with the bool ``(h, w)`` convex hull of the inliers, or None when it covers less
    than ``min_hull`` of the frame."""
    hull = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(inliers).astype(np.int32)), 1)
    return (H, hull > 0) if hull.mean() >= min_hull else None


def area_ratio(H: np.ndarray, h: int, w: int) -> float:
    """How much a homography's local area scale varies over an ``h x w`` frame: max / min over the
    corners of ``det J(p) = det(H) / (h_3 . p)^3``; ``inf`` when it flips orientation somewhere (a
    surface seen by the camera from the projector's side cannot mirror the image).

    Example:
        >>> area_ratio(np.eye(3), 10, 10)
        1.0
    """
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], np.float64)
    det = np.linalg.det(np.asarray(H, np.float64)) / (corners @ np.asarray(H, np.float64)[2]) ** 3  # [4]
    return float(det.max() / det.min()) if (det > 0).all() else math.inf


class SiftHomography:
    """SIFT keypoints, the ratio test and a RANSAC homography between two grey images.

    ``estimator(gray0, gray1)`` returns ``(H, status, inliers)``: ``H`` None unless ``status`` is ``"ok"``
    (else ``"too-few-matches"``, ``"no-homography"`` or ``"degenerate"``), and the RANSAC inlier count.
    RANSAC is seeded, so the result is reproducible.
    """

    RATIO = 0.75
    RANSAC_THRESHOLD = 3.0

    def __init__(self) -> None:
        self._sift = cv2.SIFT_create()
        self._matcher = cv2.BFMatcher(cv2.NORM_L2)

    def __call__(self, gray0: np.ndarray, gray1: np.ndarray) -> tuple[np.ndarray | None, str, int]:
        h, w = gray0.shape
        kp0, des0 = self._sift.detectAndCompute(gray0, None)
        kp1, des1 = self._sift.detectAndCompute(gray1, None)
        good = []
        if des0 is not None and des1 is not None and len(kp1) >= 2:
            for pair in self._matcher.knnMatch(des0, des1, k=2):
                if len(pair) == 2 and pair[0].distance < self.RATIO * pair[1].distance:
                    good.append(pair[0])
        if len(good) < 4:
            return None, "too-few-matches", 0
        src = np.float32([kp0[m.queryIdx].pt for m in good])  # [N, 2] projected
        dst = np.float32([kp1[m.trainIdx].pt for m in good])  # [N, 2] captured
        cv2.setRNGSeed(0)
        H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, self.RANSAC_THRESHOLD)
        if H is None:
            return None, "no-homography", 0
        if not proper_homography(H, h, w):
            return None, "degenerate", int(inliers.sum())
        return H, "ok", int(inliers.sum())
