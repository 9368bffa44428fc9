"""A projector-camera pair looking at a surface: exact forward and backward maps by ray casting.

World frame = projector frame: the projector sits at the origin looking along +z (x right, y down).
The camera pose is ``cam_from_world``: ``X_cam = R (X_world - C)``.

* forward map (flow): projector pixel -> projector ray -> first surface hit -> camera pixel.
* backward map (rendering): camera pixel -> camera ray -> first surface hit -> projector pixel.

Both are ray casts, so neither inverts the other numerically (only lens undistortion iterates, to
< 1e-6 px). Occlusion and shadow are physical: a lit point the camera's ray meets only after another
surface point is occluded; a seen point the projector's ray meets only after another is in shadow.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..utils.jit import jit
from .lens import Lens, in_frame1, project1, ray1
from .surface import CYLINDER_CONVEX, SPHERE_CONVEX, Surface, convex_sees1, hit1, never_hidden1, single1

# Why a projected pixel is invalid (bit flags, recorded per sample as pixel counts).
MISS, OUT_OF_FRAME, OCCLUDED, LENS, NEAR_EDGE = 1, 2, 4, 8, 16
REASONS = {"miss": MISS, "out_of_frame": OUT_OF_FRAME, "occluded": OCCLUDED, "lens": LENS, "near_edge": NEAR_EDGE}
PROJECTOR_FOOTPRINT = 0.5  # a projector pixel lights +-0.5 px around its centre
_VISIBILITY_TOL = 1e-7  # relative distance: a hit this close to the point is the point itself


@dataclass(frozen=True)
class Scene:
    """Projector lens at the world origin, camera lens at pose ``(R, C)``, and a surface."""

    projector: Lens
    camera: Lens
    R: np.ndarray  # cam_from_world rotation, (3, 3)
    C: np.ndarray  # camera centre in the world frame, (3,)
    surface: Surface

    def to_dict(self) -> dict:
        return {
            "projector": self.projector.to_dict(),
            "camera": self.camera.to_dict(),
            "cam_R": self.R.tolist(),
            "cam_C": self.C.tolist(),
            "surface": self.surface.to_dict(),
        }


@dataclass(frozen=True)
class ForwardMap:
    """Result of :func:`forward`: camera positions of projector points, validity and reasons."""

    uv: np.ndarray  # (2, N) float64 camera pixel coordinates (meaningless where not valid)
    valid: np.ndarray  # (N,) bool
    reason: np.ndarray  # (N,) uint8 bit flags of REASONS, 0 where valid


def forward(scene: Scene, pts: np.ndarray) -> ForwardMap:
    """Map projector pixels ``pts`` ``(2, N)`` (rows x, y) to camera pixels.

    Convention: ``uv[:, i] - pts[:, i]`` is the ground-truth flow (projected -> captured) at
    ``pts[:, i]``. A point is valid when its projector ray hits the surface, the camera sees that
    point first (no occlusion), and it lands in the camera frame ``[0, W-1] x [0, H-1]``.
    """
    uv, reason = _forward_many(
        scene.projector.packed, scene.camera.packed, *_pose(scene), *scene.surface.packed, _points(pts)
    )
    return ForwardMap(uv, reason == 0, reason)


def backward(scene: Scene, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map camera pixels ``pts`` ``(2, N)`` to the projector pixels that light them.

    Returns:
        ``(xy, lit)``: projector pixel coordinates ``(2, N)`` and a mask of camera pixels that see a
        surface point lit by the projector (inside its pixels' footprint ``[-0.5, W-0.5] x
        [-0.5, H-0.5]``, not in shadow).
    """
    return _backward_many(
        scene.camera.packed, scene.projector.packed, *_pose(scene), *scene.surface.packed, _points(pts)
    )


def _pose(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(scene.R, np.float64), np.ascontiguousarray(scene.C, np.float64)


def _points(pts: np.ndarray) -> np.ndarray:
    pts = np.ascontiguousarray(pts, np.float64)
    if pts.ndim != 2 or pts.shape[0] != 2:
        raise ValueError(f"points must be a (2, N) array of (x, y) rows, got shape {pts.shape}")
    return pts


# Per-pixel kernels (numba): one ray cast, projection and visibility test per point, no temporaries.


@jit(inline=True)
def _visible1(g, terms, ex, ey, ez, x, y, z):  # noqa: ANN001, ANN202
    """True where the first surface hit from the eye ``e`` towards the point ``X`` is ``X`` itself."""
    if g[0] == CYLINDER_CONVEX or g[0] == SPHERE_CONVEX:
        return convex_sees1(g, ex, ey, ez, x, y, z)
    rx, ry, rz = x - ex, y - ey, z - ez
    dist = np.sqrt(rx * rx + ry * ry + rz * rz)
    if dist > 0:
        inv = 1.0 / dist
        rx, ry, rz = rx * inv, ry * inv, rz * inv
    if single1(g, ex, ey, ez, rx, ry, rz):
        return True
    t = hit1(g, terms, ex, ey, ez, rx, ry, rz, dist)
    return np.isfinite(t) and t > dist * (1 - _VISIBILITY_TOL)


@jit(inline=True)
def _next_shifts(ok, sx, sy, sx1, sy1, prev_ok):  # noqa: ANN001, ANN202
    """The two shifts the next pixel extrapolates from: ``(s, s_prev)``; after a failure, none (0, so the
    guess is no shift), and right after one, ``s`` twice (the guess is the last shift, not twice it)."""
    if not ok:
        return 0.0, 0.0, 0.0, 0.0
    return (sx, sy, sx1, sy1) if prev_ok else (sx, sy, sx, sy)


@jit
def _forward_many(proj, cam, R, C, g, terms, pts):  # noqa: ANN001, ANN202
    n = pts.shape[1]
    uv, reason = np.empty((2, n)), np.empty(n, np.uint8)
    always_seen = never_hidden1(g, C[0], C[1], C[2])
    t1 = t2 = np.nan  # the previous two rays' distances: neighbouring pixels hit close together
    sx1 = sy1 = sx2 = sy2 = 0.0  # the previous two pixels' undistortion shifts, the same way
    prev_ok = False
    for i in range(n):
        dx, dy, dz, lens_ok, sx, sy = ray1(proj, pts[0, i], pts[1, i], 2.0 * sx1 - sx2, 2.0 * sy1 - sy2)
        sx1, sy1, sx2, sy2 = _next_shifts(lens_ok, sx, sy, sx1, sy1, prev_ok)
        prev_ok = lens_ok
        t = hit1(g, terms, 0.0, 0.0, 0.0, dx, dy, dz, 2.0 * t1 - t2)
        hit = np.isfinite(t)
        t1, t2 = (t, t1) if hit else (np.nan, np.nan)
        if not hit:
            t = 0.0
        x, y, z = dx * t, dy * t, dz * t
        px, py, pz = x - C[0], y - C[1], z - C[2]
        u, v, cam_ok = project1(
            cam,
            R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz,
            R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz,
            R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz,
        )
        frame_ok = in_frame1(cam, u, v, 1e-6)
        r = 0 if lens_ok and cam_ok else LENS
        if not hit:
            r |= MISS
        elif not frame_ok:
            r |= OUT_OF_FRAME
        elif lens_ok and cam_ok and not always_seen and not _visible1(g, terms, C[0], C[1], C[2], x, y, z):
            r |= OCCLUDED
        uv[0, i], uv[1, i], reason[i] = u, v, r
    return uv, reason


@jit
def _backward_many(cam, proj, R, C, g, terms, pts):  # noqa: ANN001, ANN202
    n = pts.shape[1]
    xy, lit = np.empty((2, n)), np.empty(n, np.bool_)
    always_lit = never_hidden1(g, 0.0, 0.0, 0.0)
    t1 = t2 = np.nan
    sx1 = sy1 = sx2 = sy2 = 0.0
    prev_ok = False
    for i in range(n):
        cx, cy, cz, lens_ok, sx, sy = ray1(cam, pts[0, i], pts[1, i], 2.0 * sx1 - sx2, 2.0 * sy1 - sy2)
        sx1, sy1, sx2, sy2 = _next_shifts(lens_ok, sx, sy, sx1, sy1, prev_ok)
        prev_ok = lens_ok
        dx = R[0, 0] * cx + R[1, 0] * cy + R[2, 0] * cz  # R^T: camera -> world
        dy = R[0, 1] * cx + R[1, 1] * cy + R[2, 1] * cz
        dz = R[0, 2] * cx + R[1, 2] * cy + R[2, 2] * cz
        t = hit1(g, terms, C[0], C[1], C[2], dx, dy, dz, 2.0 * t1 - t2)
        hit = np.isfinite(t)
        t1, t2 = (t, t1) if hit else (np.nan, np.nan)
        if not hit:
            t = 0.0
        x, y, z = C[0] + dx * t, C[1] + dy * t, C[2] + dz * t
        u, v, proj_ok = project1(proj, x, y, z)
        ok = hit and lens_ok and proj_ok and in_frame1(proj, u, v, PROJECTOR_FOOTPRINT)
        xy[0, i], xy[1, i], lit[i] = u, v, ok and (always_lit or _visible1(g, terms, 0.0, 0.0, 0.0, x, y, z))
    return xy, lit


@lru_cache(maxsize=4)
def pixel_grid(height: int, width: int) -> np.ndarray:
    """All pixel centres of an ``height x width`` frame as ``(2, H*W)`` float64 rows (x, y), row-major.

    Cached (every sample of a dataset uses the same grid), hence read-only.
    """
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    grid = np.stack([xs.ravel(), ys.ravel()])
    grid.flags.writeable = False
    return grid


def look_at(C: np.ndarray, target: np.ndarray, offset_px: tuple[float, float], roll: float, lens: Lens) -> np.ndarray:
    """``cam_from_world`` rotation of a camera at ``C`` that sees ``target`` at principal point + offset.

    Args:
        offset_px: where ``target`` lands relative to the principal point, in pixels (x, y).
        roll: rotation about the optical axis, radians.
    """
    z = (target - C) / np.linalg.norm(target - C)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    base = np.stack([x, y, z])
    cr, sr = np.cos(roll), np.sin(roll)
    r_roll = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    want = np.array([offset_px[0] / lens.fx, offset_px[1] / lens.fy, 1.0])
    return _rotation_between(np.array([0.0, 0.0, 1.0]), want / np.linalg.norm(want)) @ r_roll @ base


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    v = np.cross(a, b)
    s = np.linalg.norm(v)
    return rotation_about(v, float(np.arctan2(s, np.dot(a, b)))) if s > 1e-15 else np.eye(3)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix of ``angle`` radians about ``axis`` (any length)."""
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
