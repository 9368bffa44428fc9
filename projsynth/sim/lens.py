"""Pinhole lenses with OpenCV distortion: pixels <-> normalised rays, exactly.

Convention: pixel centres at integer coordinates; ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``;
distortion coefficients in OpenCV order ``(k1, k2, p1, p2, k3)`` acting on normalised coordinates
``(x, y) = (X / Z, Y / Z)`` of the lens frame (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..utils.jit import jit

UNDISTORT_TOL_PX = 1e-6  # Newton stops well below DESIGN's 1e-4 px requirement
_NEWTON_ITERS = 12
# A packed lens (what the kernels take):
# (fx, fy, cx, cy, k1, k2, p1, p2, k3, width, height, fold_r2, distorted, 1 / fx, 1 / fy)


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

    @cached_property
    def max_radius(self) -> float:
        """Normalised radius beyond which the radial model folds back (not a physical lens)."""
        return _fold_radius(self.dist)

    @cached_property
    def packed(self) -> tuple[float, ...]:
        """The lens as the tuple of floats the numba kernels take (field order: the comment at the top of this module).

        A tuple of scalars, not an array: kernels receive it by value, without reference counting.
        """
        fold = self.max_radius
        values = (
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            *_coefficients(self.dist),
            self.width,
            self.height,
            fold * fold,
            self.distorted,
            1.0 / self.fx,
            1.0 / self.fy,
        )
        return tuple(float(x) for x in values)

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
    """Apply OpenCV's radial + tangential model to normalised coordinates (arrays of any one shape).

    Convention: input and output are normalised lens-frame coordinates (not pixels).
    """
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    xd, yd = _distort_many(x.ravel(), y.ravel(), *_coefficients(dist))
    return xd.reshape(x.shape), yd.reshape(x.shape)


def undistort(
    xd: np.ndarray, yd: np.ndarray, dist: tuple[float, ...], scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Invert :func:`distort` by Newton's method, point by point.

    Args:
        xd, yd: distorted normalised coordinates.
        dist: OpenCV coefficients ``(k1, k2, p1, p2, k3)``.
        scale: focal length in pixels, to express the residual in pixels.

    Returns:
        ``(x, y, ok)``: undistorted normalised coordinates and a mask of points whose residual is below
        ``UNDISTORT_TOL_PX`` pixels inside the lens's unfolded radius.
    """
    xd, yd = np.broadcast_arrays(np.asarray(xd, np.float64), np.asarray(yd, np.float64))
    x, y, ok = _undistort_many(xd.ravel(), yd.ravel(), *_coefficients(dist), scale, _fold_radius(dist) ** 2)
    return x.reshape(xd.shape), y.reshape(xd.shape), ok.reshape(xd.shape)


def pixels_to_rays(lens: Lens, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project pixels (1-D arrays) to unit ray directions in the lens frame.

    Returns:
        ``(dirs, ok)``: ``(3, N)`` float64 unit vectors and a mask of pixels that undistort exactly.
    """
    u, v = np.asarray(u, np.float64).ravel(), np.asarray(v, np.float64).ravel()
    if u.shape != v.shape:
        raise ValueError(f"pixels_to_rays needs as many u as v, got {u.size} and {v.size}")
    return _rays_many(lens.packed, u, v)


def project_points(lens: Lens, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project lens-frame 3-D points ``(3, N)`` to pixels.

    Returns:
        ``(u, v, ok)``: pixel coordinates and a mask of points in front of the lens and inside its
        unfolded radius (outside it the polynomial model maps several rays to one pixel).
    """
    pts = np.ascontiguousarray(pts, np.float64)
    if pts.ndim != 2 or pts.shape[0] != 3:
        raise ValueError(f"project_points needs lens-frame points (3, N), got shape {pts.shape}")
    return _project_many(lens.packed, pts)


def _coefficients(dist: tuple[float, ...]) -> tuple[float, ...]:
    if len(dist) != 5:
        raise ValueError(f"distortion needs 5 coefficients (k1, k2, p1, p2, k3), got {len(dist)}")
    return tuple(float(c) for c in dist)


# Per-point kernels (numba), taking a packed lens (see the top of this module).


@jit(inline=True)
def distort1(x: float, y: float, k1: float, k2: float, p1: float, p2: float, k3: float) -> tuple[float, float]:
    """:func:`distort` of one point."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    return x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2


@jit(inline=True)
def undistort1(
    xd: float,
    yd: float,
    k1: float,
    k2: float,
    p1: float,
    p2: float,
    k3: float,
    scale: float,
    fold_r2: float,
    x0: float,
    y0: float,
) -> tuple[float, float, bool]:
    """:func:`undistort` of one point: Newton on the 2 x 2 Jacobian, from the guess ``(x0, y0)``."""
    x, y = x0, y0
    for step in range(_NEWTON_ITERS + 1):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd  # distort1(x, y) - (xd, yd)
        ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        if max(abs(ex), abs(ey)) * scale < UNDISTORT_TOL_PX * 0.01 or step == _NEWTON_ITERS:
            break
        dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # d radial / d (x or y), over x or y
        j11 = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        j22 = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        j12 = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        det = j11 * j22 - j12 * j12
        x, y = x - (j22 * ex - j12 * ey) / det, y - (j11 * ey - j12 * ex) / det
    tol = UNDISTORT_TOL_PX / scale  # UNDISTORT_TOL_PX in normalised units, for the residual at the returned point
    ok = ex * ex + ey * ey < tol * tol and r2 < fold_r2
    return x, y, ok


@jit(inline=True)
def ray1(lens: tuple, u: float, v: float, sx: float, sy: float) -> tuple[float, float, float, bool, float, float]:
    """Unit lens-frame ray ``(dx, dy, dz)`` of pixel ``(u, v)``, whether it undistorts exactly, and the
    undistortion shift ``(x - x_d, y - y_d)`` in normalised coordinates (0 where it failed).

    ``(sx, sy)``: a guess of that shift (extrapolated from the neighbouring pixels', or 0): Newton starts
    there. The shift varies slowly, so a good guess saves most iterations; the result does not depend on
    it beyond the 1e-8 px stopping tolerance (the distortion is one-to-one inside the fold radius), and
    validity does not either: when Newton fails from the guess it starts again from no shift.
    """
    xd, yd = (u - lens[2]) * lens[13], (v - lens[3]) * lens[14]  # multiplications: divisions cost 4-5x more
    x, y, ok = xd, yd, True
    if lens[12] != 0.0:
        scale = max(lens[0], lens[1])
        x, y, ok = undistort1(xd, yd, lens[4], lens[5], lens[6], lens[7], lens[8], scale, lens[11], xd + sx, yd + sy)
        if not ok and (sx != 0.0 or sy != 0.0):  # a guess past the fold must not decide validity: start over
            x, y, ok = undistort1(xd, yd, lens[4], lens[5], lens[6], lens[7], lens[8], scale, lens[11], xd, yd)
    inv = 1.0 / np.sqrt(x * x + y * y + 1.0)
    return x * inv, y * inv, inv, ok, (x - xd) if ok else 0.0, (y - yd) if ok else 0.0  # no bad guesses passed on


@jit(inline=True)
def project1(lens: tuple, X: float, Y: float, Z: float) -> tuple[float, float, bool]:
    """Pixel ``(u, v)`` of lens-frame point ``(X, Y, Z)``, and whether it is in front and unfolded."""
    ok = Z > 1e-9
    iz = 1.0 / Z if ok else 1.0
    x, y = X * iz, Y * iz
    if lens[12] != 0.0:
        ok = ok and x * x + y * y < lens[11]
        x, y = distort1(x, y, lens[4], lens[5], lens[6], lens[7], lens[8])
    return lens[0] * x + lens[2], lens[1] * y + lens[3], ok


@jit(inline=True)
def in_frame1(lens: tuple, u: float, v: float, margin: float) -> bool:
    """True where ``(u, v)`` lies in ``[-margin, W-1+margin] x [-margin, H-1+margin]``.

    ``margin=1e-6`` (border pixels survive a round trip's rounding) is the region where bilinear sampling
    needs no extrapolation; ``margin=0.5`` is the frame's physical extent (each pixel covers +-0.5 px
    around its centre).
    """
    return -margin <= u <= lens[9] - 1 + margin and -margin <= v <= lens[10] - 1 + margin


@jit
def _distort_many(x, y, k1, k2, p1, p2, k3):  # noqa: ANN001, ANN202
    xd, yd = np.empty_like(x), np.empty_like(y)
    for i in range(x.size):
        xd[i], yd[i] = distort1(x[i], y[i], k1, k2, p1, p2, k3)
    return xd, yd


@jit
def _undistort_many(xd, yd, k1, k2, p1, p2, k3, scale, fold_r2):  # noqa: ANN001, ANN202
    x, y, ok = np.empty_like(xd), np.empty_like(yd), np.empty(xd.size, np.bool_)
    for i in range(xd.size):
        x[i], y[i], ok[i] = undistort1(xd[i], yd[i], k1, k2, p1, p2, k3, scale, fold_r2, xd[i], yd[i])
    return x, y, ok


@jit
def _rays_many(lens, u, v):  # noqa: ANN001, ANN202
    dirs, ok = np.empty((3, u.size)), np.empty(u.size, np.bool_)
    for i in range(u.size):
        dirs[0, i], dirs[1, i], dirs[2, i], ok[i], _, _ = ray1(lens, u[i], v[i], 0.0, 0.0)
    return dirs, ok


@jit
def _project_many(lens, pts):  # noqa: ANN001, ANN202
    n = pts.shape[1]
    u, v, ok = np.empty(n), np.empty(n), np.empty(n, np.bool_)
    for i in range(n):
        u[i], v[i], ok[i] = project1(lens, pts[0, i], pts[1, i], pts[2, i])
    return u, v, ok
