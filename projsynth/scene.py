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

import numpy as np

from .lens import Lens, in_frame, pixels_to_rays, project_points
from .surface import Surface, intersect, single_crossing

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
    dirs, lens_ok = pixels_to_rays(scene.projector, pts[0], pts[1])
    t, hit = intersect(scene.surface, np.zeros((3, 1)), dirs)
    X = dirs * np.where(hit, t, 0.0)
    u, v, cam_ok = project_points(scene.camera, scene.R @ (X - scene.C[:, None]))
    frame_ok = in_frame(scene.camera, u, v)
    seen = _visible_from(scene.surface, scene.C, X, hit & lens_ok & cam_ok & frame_ok)
    reason = np.where(lens_ok & cam_ok, 0, LENS) | np.where(hit, 0, MISS)
    reason |= np.where(hit & ~frame_ok, OUT_OF_FRAME, 0)
    reason |= np.where(hit & lens_ok & cam_ok & frame_ok & ~seen, OCCLUDED, 0)
    reason = reason.astype(np.uint8)
    return ForwardMap(np.stack([u, v]), reason == 0, reason)


def backward(scene: Scene, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map camera pixels ``pts`` ``(2, N)`` to the projector pixels that light them.

    Returns:
        ``(xy, lit)``: projector pixel coordinates ``(2, N)`` and a mask of camera pixels that see a
        surface point lit by the projector (inside its pixels' footprint ``[-0.5, W-0.5] x
        [-0.5, H-0.5]``, not in shadow).
    """
    dirs_cam, lens_ok = pixels_to_rays(scene.camera, pts[0], pts[1])
    dirs = scene.R.T @ dirs_cam
    t, hit = intersect(scene.surface, scene.C[:, None], dirs)
    X = scene.C[:, None] + dirs * np.where(hit, t, 0.0)
    u, v, proj_ok = project_points(scene.projector, X)
    lit = hit & lens_ok & proj_ok & in_frame(scene.projector, u, v, margin=PROJECTOR_FOOTPRINT)
    lit &= _visible_from(scene.surface, np.zeros(3), X, lit)
    return np.stack([u, v]), lit


def _visible_from(surface: Surface, eye: np.ndarray, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """True where the first surface hit from ``eye`` towards ``X`` ``(3, N)`` is ``X`` itself."""
    ray = X - eye[:, None]
    dist = np.sqrt((ray * ray).sum(0))
    dirs = ray / np.where(dist > 0, dist, 1.0)
    seen = mask & single_crossing(surface, eye[:, None], dirs)
    idx = np.nonzero(mask & ~seen)[0]
    if idx.size:
        t, hit = intersect(surface, eye[:, None], dirs[:, idx])
        seen[idx] = hit & (t > dist[idx] * (1 - _VISIBILITY_TOL))
    return seen


def pixel_grid(height: int, width: int) -> np.ndarray:
    """All pixel centres of an ``height x width`` frame as ``(2, H*W)`` float64 rows (x, y), row-major."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([xs.ravel(), ys.ravel()])


def look_at(C: np.ndarray, target: np.ndarray, offset_px: tuple[float, float], roll: float,
            lens: Lens) -> np.ndarray:
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
