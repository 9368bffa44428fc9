"""Pinhole lenses with OpenCV distortion: pixels <-> normalised rays, exactly.

Convention: pixel centres at integer coordinates; ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``;
distortion coefficients in OpenCV order ``(k1, k2, p1, p2, k3)`` acting on normalised coordinates
``(x, y) = (X / Z, Y / Z)`` of the lens frame (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNDISTORT_TOL_PX = 1e-6  # Newton stops well below DESIGN's 1e-4 px requirement
_NEWTON_ITERS = 12


@dataclass(frozen=True)
class Lens:
    """Intrinsics and distortion of a projector or camera with an ``height x width`` frame."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    width: int = 512
    height: int = 384

    @property
    def distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @property
    def max_radius(self) -> float:
        """Normalised radius beyond which the radial model folds back (not a physical lens)."""
        return _fold_radius(self.dist)

    def to_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "dist": list(self.dist)}


def _fold_radius(dist: tuple[float, ...]) -> float:
    """Smallest undistorted radius where d r_d / d r drops to 0.05 (or inf when it never does)."""
    k1, k2, _, _, k3 = dist
    r = np.linspace(0.0, 3.0, 3001)
    r2 = r * r
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
    bad = np.nonzero(slope < 0.05)[0]
    return float(r[bad[0] - 1]) if bad.size else float("inf")


def distort(x: np.ndarray, y: np.ndarray, dist: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Apply OpenCV's radial + tangential model to normalised coordinates.

    Convention: input and output are normalised lens-frame coordinates (not pixels).
    """
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    return xd, yd


def undistort(
    xd: np.ndarray, yd: np.ndarray, dist: tuple[float, ...], scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Invert :func:`distort` by Newton's method.

    Args:
        xd, yd: distorted normalised coordinates.
        dist: OpenCV coefficients ``(k1, k2, p1, p2, k3)``.
        scale: focal length in pixels, to express the residual in pixels.

    Returns:
        ``(x, y, ok)``: undistorted normalised coordinates and a mask of points whose residual is below
        ``UNDISTORT_TOL_PX`` pixels inside the lens's unfolded radius.
    """
    k1, k2, p1, p2, k3 = dist
    x, y = xd.copy(), yd.copy()
    for _ in range(_NEWTON_ITERS):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # d radial / d (x or y), over x or y
        ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        j11 = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        j22 = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        j12 = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        det = j11 * j22 - j12 * j12
        x = x - (j22 * ex - j12 * ey) / det
        y = y - (j11 * ey - j12 * ex) / det
        if max(np.abs(ex).max(initial=0.0), np.abs(ey).max(initial=0.0)) * scale < UNDISTORT_TOL_PX * 0.1:
            break
    rx, ry = distort(x, y, dist)
    residual = np.hypot(rx - xd, ry - yd) * scale
    ok = (residual < UNDISTORT_TOL_PX) & (x * x + y * y < _fold_radius(dist) ** 2)
    return x, y, ok


def pixels_to_rays(lens: Lens, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project pixels to unit ray directions in the lens frame.

    Returns:
        ``(dirs, ok)``: ``(3, N)`` float64 unit vectors and a mask of pixels that undistort exactly.
    """
    xd = (u - lens.cx) / lens.fx
    yd = (v - lens.cy) / lens.fy
    if lens.distorted:
        x, y, ok = undistort(xd, yd, lens.dist, max(lens.fx, lens.fy))
    else:
        x, y, ok = xd, yd, np.ones(xd.shape, bool)
    inv = 1.0 / np.sqrt(x * x + y * y + 1.0)
    return np.stack([x * inv, y * inv, inv]), ok


def project_points(lens: Lens, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project lens-frame 3-D points ``(3, N)`` to pixels.

    Returns:
        ``(u, v, ok)``: pixel coordinates and a mask of points in front of the lens and inside its
        unfolded radius (outside it the polynomial model maps several rays to one pixel).
    """
    z = pts[2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    x, y = pts[0] / zs, pts[1] / zs
    ok = front
    if lens.distorted:
        ok = ok & (x * x + y * y < lens.max_radius**2)
        x, y = distort(x, y, lens.dist)
    return lens.fx * x + lens.cx, lens.fy * y + lens.cy, ok


def in_frame(lens: Lens, u: np.ndarray, v: np.ndarray, margin: float = 1e-6) -> np.ndarray:
    """True where ``(u, v)`` lies in ``[-margin, W-1+margin] x [-margin, H-1+margin]``.

    The default (1e-6 px, so border pixels survive a round trip's rounding) is the region where
    bilinear sampling needs no extrapolation; ``margin=0.5`` is the frame's physical extent (each
    pixel covers +-0.5 px around its centre).
    """
    return (u >= -margin) & (u <= lens.width - 1 + margin) & (v >= -margin) & (v <= lens.height - 1 + margin)
