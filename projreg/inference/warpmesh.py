"""Warp meshes: a :class:`~projreg.inference.warpmaps.WarpMap` sampled on a grid of projector pixels, as a
mesh that show software draws (an ``.obj`` of ``projreg warp``).

Convention: a vertex at every ``step``-th projector pixel of each row and column, the last row and
column always included (the mesh spans the frame), at position ``(x, y, 0)`` in projector pixels
(pixel centres at integers, ``x`` to the right, ``y`` down), with the map's UV there as its texture
coordinate (an STMap's convention: ``v`` up). Each grid cell whose four corners show content is two
triangles split along the top-left to bottom-right diagonal, (top-left, bottom-left, bottom-right)
and (top-left, bottom-right, top-right): counter-clockwise as the frame appears on screen, so a tool
that shows the mesh upright (``y`` flipped to point up) sees their front. A renderer interpolates UV
linearly over each triangle; :func:`drawn_map` does the same on every projector pixel, which is what
the mesh's error against the full map is measured on.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from ..errors import ProjregError
from .warpmaps import OUTSIDE, WarpMap

DEFAULT_STEP = 16  # projector pixels between vertices: sub-pixel error on smooth surfaces (docs/show.md)


@dataclass(frozen=True)
class GridMesh:
    """A warp map sampled on a grid (module convention).

    ``xs``, ``ys``: int ``(nx,)``, ``(ny,)``, the projector columns and rows of the vertices; ``uv``:
    float32 ``(ny, nx, 2)``, the map's UV at each vertex (``OUTSIDE`` where it shows nothing); ``faces``:
    bool ``(ny - 1, nx - 1)``, the cells drawn (two triangles each); ``shape``: the projector frame
    ``(H, W)``; ``camera_size``: the map's camera frame.
    """

    xs: np.ndarray
    ys: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    shape: tuple[int, int]
    camera_size: tuple[int, int]


def grid_positions(n: int, step: int) -> np.ndarray:
    """``0, step, 2 step, ...`` below ``n``, and ``n - 1``: the vertices of a side of ``n`` pixels."""
    at = np.arange(0, n, step)
    return at if at[-1] == n - 1 else np.append(at, n - 1)


def grid_mesh(m: WarpMap, step: int = DEFAULT_STEP) -> GridMesh:
    """The mesh of ``m`` with a vertex every ``step`` projector pixels (module convention).

    Raises:
        ProjregError: ``step`` under 1 or over the shorter side of the frame less one, named ``--step``.

    Example:
        >>> from projreg.inference.warpmaps import warp_map
        >>> mesh = grid_mesh(warp_map(np.zeros((5, 9, 2), np.float32)), step=4)
        >>> mesh.xs.tolist(), mesh.ys.tolist(), mesh.faces.shape
        ([0, 4, 8], [0, 4], (1, 2))
    """
    h, w = m.shown.shape
    if isinstance(step, bool) or not isinstance(step, int | np.integer) or not 1 <= step <= min(h, w) - 1:
        raise ProjregError(
            f"--step {step}: expected an integer in 1..{min(h, w) - 1} (projector pixels between vertices; the "
            f"projector frame is {w}x{h})"
        )
    xs, ys = grid_positions(w, step), grid_positions(h, step)
    shown = m.shown[np.ix_(ys, xs)]  # [ny, nx]
    faces = shown[:-1, :-1] & shown[:-1, 1:] & shown[1:, :-1] & shown[1:, 1:]
    return GridMesh(xs, ys, m.uv[np.ix_(ys, xs)], faces, (h, w), m.camera_size)


def drawn_map(mesh: GridMesh) -> WarpMap:
    """The map a renderer draws from ``mesh``: UV interpolated linearly over each triangle, shown on
    the projector pixels its faces cover (their edges included). Computed one row of cells at a time,
    so that a 4K frame needs memory for a band of ``step`` rows only."""
    h, w = mesh.shape
    nx, ny = len(mesh.xs), len(mesh.ys)
    cx = np.minimum(np.searchsorted(mesh.xs, np.arange(w), side="right") - 1, nx - 2)  # [W] cell of each column
    s = (np.arange(w) - mesh.xs[cx]) / (mesh.xs[cx + 1] - mesh.xs[cx])  # [W] in [0, 1] across the cell
    on_x = (s == 0) & (cx > 0)  # [W] on a vertical grid line: also in the cell to its left
    S, c = s[None, :, None], cx[None, :]  # [1, W, 1], [1, W]
    uv = np.full((h, w, 2), OUTSIDE, np.float32)
    covered = np.zeros((h, w), bool)
    for j in range(ny - 1):
        y0, y1 = int(mesh.ys[j]), int(mesh.ys[j + 1])
        rows = np.arange(y0, y1 + (j == ny - 2))  # [B] the band of rows of this row of cells (the last: and y1)
        T = ((rows - y0) / (y1 - y0))[:, None, None]  # [B, 1, 1]
        tl, tr = mesh.uv[j, c].astype(np.float64), mesh.uv[j, c + 1].astype(np.float64)  # [1, W, 2]
        bl, br = mesh.uv[j + 1, c].astype(np.float64), mesh.uv[j + 1, c + 1].astype(np.float64)
        lower = tl * (1 - T) + bl * (T - S) + br * S  # triangle (tl, bl, br), where t >= s
        upper = tl * (1 - S) + tr * (S - T) + br * T  # triangle (tl, br, tr), where s >= t
        faces = mesh.faces[j][c] | (on_x[None, :] & mesh.faces[j][c - 1])  # [1, W]
        band = np.repeat(faces, len(rows), axis=0)  # [B, W]
        if j > 0:  # the band's first row lies on a horizontal grid line: also in the cells above
            band[0] |= mesh.faces[j - 1][cx] | (on_x & mesh.faces[j - 1][cx - 1])
        uv[rows] = np.where(band[..., None], np.where(T >= S, lower, upper), OUTSIDE)
        covered[rows] = band
    return WarpMap(uv, covered, mesh.camera_size)


def mesh_error(m: WarpMap, mesh: GridMesh) -> dict[str, float]:
    """How well ``mesh`` draws ``m``: ``error_mean``, ``error_max`` (camera pixels, over the pixels that
    ``m`` shows and the faces cover; 0 when there are none), ``covered`` (the share of ``m``'s shown
    pixels the faces cover) and ``beyond`` (the share of the covered pixels that ``m`` does not show:
    holes smaller than a cell)."""
    drawn = drawn_map(mesh)
    both = drawn.shown & m.shown
    err = drawn.error(m)[both]
    return {
        "error_mean": float(err.mean()) if err.size else 0.0,
        "error_max": float(err.max()) if err.size else 0.0,
        "covered": float(both.sum() / m.shown.sum()),
        "beyond": float((drawn.shown & ~m.shown).sum() / max(1, drawn.shown.sum())),
    }


def used_vertices(mesh: GridMesh) -> np.ndarray:
    """The vertices some face uses, bool ``(ny, nx)``: the ones an OBJ of the mesh holds."""
    ny, nx = mesh.faces.shape
    used = np.zeros((ny + 1, nx + 1), bool)
    for dy in (0, 1):
        for dx in (0, 1):
            used[dy : ny + dy, dx : nx + dx] |= mesh.faces
    return used


def obj_text(mesh: GridMesh, comments: list[str]) -> str:
    """The mesh as Wavefront OBJ text: ``comments`` as ``#`` lines, then the vertices the faces use
    (``v x y 0`` and ``vt u v``, one index for both) and the triangles (``f a/a b/b c/c``, 1-based)."""
    used = used_vertices(mesh)
    index = np.cumsum(used).reshape(used.shape)  # 1-based OBJ index where used
    gy, gx = np.nonzero(used)
    r, c = np.nonzero(mesh.faces)  # [F] cells drawn, row by row
    tl, tr, bl, br = index[r, c], index[r, c + 1], index[r + 1, c], index[r + 1, c + 1]
    triangles = np.stack([tl, bl, br, tl, br, tr], 1).reshape(-1, 3)  # [2F, 3], the two of a cell together
    out = io.StringIO()
    out.write("".join(f"# {line}\n" for line in comments))
    np.savetxt(out, np.stack([mesh.xs[gx], mesh.ys[gy]], 1), fmt="v %d %d 0")
    np.savetxt(out, mesh.uv[gy, gx].astype(np.float64), fmt="vt %.9g %.9g")
    np.savetxt(out, np.repeat(triangles, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
    return out.getvalue()
