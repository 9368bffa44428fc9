"""The cases of the warp tests: an analytic flow (a homography and a bend) into a camera of another size,
and an OBJ reader and rasteriser written apart from the code under test."""

import numpy as np

H, W = 48, 64  # the projector frame
CAMERA = (60, 80)  # another size than the projector's, as a real camera


def bent_homography(h=H, w=W):
    """Projector pixel -> camera position: a homography into the larger camera frame plus a smooth bend,
    part of the frame landing outside the camera's; returned as the flow."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    hom = np.array([[1.3, 0.08, -4.0], [-0.05, 1.2, 3.0], [4e-4, 2e-4, 1.0]])
    q = np.stack([x, y, np.ones_like(x)], -1) @ hom.T
    cx, cy = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
    cy = cy + 2.5 * np.sin(2 * np.pi * x / w)  # the bend: a wave along the rows
    return np.stack([cx - x, cy - y], -1).astype(np.float32)


def parse_obj(text):
    """``(vertices (N, 3), uv (N, 2), triangles (F, 3) 0-based)`` of an OBJ whose faces use one index for both."""
    v = np.array([line.split()[1:] for line in text.splitlines() if line.startswith("v ")], float)
    vt = np.array([line.split()[1:] for line in text.splitlines() if line.startswith("vt ")], float)
    f = [[int(c.split("/")[0]) for c in line.split()[1:]] for line in text.splitlines() if line.startswith("f ")]
    for line in text.splitlines():
        if line.startswith("f "):
            assert all(a == b for a, b in (c.split("/") for c in line.split()[1:])), line
    return v, vt, np.array(f) - 1


def rasterise(v, vt, triangles, shape):
    """Each triangle's UV, linear over it, on the pixel centres it covers (edges included): an independent
    rendering of the OBJ, as a GPU interpolates texture coordinates."""
    uv = np.full((*shape, 2), np.nan)
    for tri in triangles:
        (x0, y0), (x1, y1), (x2, y2) = v[tri, :2]
        xs = np.arange(int(min(x0, x1, x2)), int(max(x0, x1, x2)) + 1)
        ys = np.arange(int(min(y0, y1, y2)), int(max(y0, y1, y2)) + 1)
        px, py = np.meshgrid(xs, ys)
        det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        a = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / det
        b = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / det
        c = 1 - a - b
        inside = (a >= -1e-9) & (b >= -1e-9) & (c >= -1e-9)
        value = a[..., None] * vt[tri[0]] + b[..., None] * vt[tri[1]] + c[..., None] * vt[tri[2]]
        uv[py[inside], px[inside]] = value[inside]
    return uv
