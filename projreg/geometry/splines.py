"""Smooth surface models of a flow: a cubic B-spline fitted by weighted, regularised least squares on a
coarse grid of samples, and a finer detail P-spline accepted only where it predicts held-out samples.

Convention: fields float32 ``(H, W)`` or ``(H, W, 2)`` on the projected grid.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np

from .images import gaussian, ramp
from .linalg import one_blas_thread, solve_spd


def bspline_basis(n: int, k: int) -> np.ndarray:
    """Uniform cubic B-spline basis ``(n, k)``: ``k`` control points spanning samples ``0 .. n-1``.

    The first and last control points lie one knot outside the frame, so the basis sums to 1 at every
    sample (a constant residual is represented exactly).

    Example:
        >>> bool(np.allclose(bspline_basis(50, 6).sum(axis=1), 1.0))
        True
    """
    t = np.arange(n) / max(n - 1, 1) * (k - 3)  # [n], sample positions in knot units
    d = np.abs(t[:, None] - (np.arange(k)[None, :] - 1))  # [n, k]
    return np.where(d < 1, 2 / 3 - d**2 + d**3 / 2, np.where(d < 2, (2 - d) ** 3 / 6, 0.0))


def fit_bspline(
    field: np.ndarray,
    weight: np.ndarray,
    grid: tuple[int, int],
    step: int = 4,
    robust: float = 1.0,
    ridge: float = 1e-3,
    iterations: int = 3,
    bend: float = 0.0,
) -> np.ndarray:
    """Robust weighted least-squares cubic B-spline fit of a 2-channel field.

    Args:
        field: float ``(H, W, 2)``; fitted on every ``step``-th pixel.
        weight: float ``(H, W)`` >= 0, the confidence of each pixel.
        grid: control points ``(kx, ky)``.
        robust: Cauchy scale (field units) of the reweighting after the first solve.
        ridge: Tikhonov weight towards zero on the control values.
        iterations: weighted solves (the first unweighted by residuals).
        bend: weight of a second-difference penalty on the control values (a P-spline): bridges
            regions without data smoothly instead of pulling them to zero.

    Returns:
        float32 ``(H, W, 2)``, the spline evaluated at every pixel.
    """
    design = spline_design(field.shape[0], field.shape[1], tuple(grid), step)
    f, w0 = design.samples(field, weight)
    with one_blas_thread():
        return design.evaluate(design.solve(f, w0, robust, ridge, iterations, bend))


@lru_cache(maxsize=8)
def spline_design(h: int, w: int, grid: tuple[int, int], step: int) -> SplineDesign:
    """The :class:`SplineDesign` of one frame size, grid and step, built once (its arrays are not written)."""
    return SplineDesign(h, w, grid, step)


class SplineDesign:
    """A cubic B-spline on one frame size and grid, sampled every ``step`` px, and its weighted robust solve.

    The basis is a tensor product, so the normal equations are built separably (one pass over the
    sample rows per basis pair) instead of from the dense ``(N, K)`` design matrix: a few milliseconds
    for a 14 x 11 grid on 12,000 samples.
    """

    def __init__(self, h: int, w: int, grid: tuple[int, int], step: int) -> None:
        kx, ky = grid
        self.grid, self.step = grid, step
        self.By, self.Bx = bspline_basis(h, ky), bspline_basis(w, kx)  # [H, ky], [W, kx]
        self.by, self.bx = self.By[::step], self.Bx[::step]  # [h', ky], [w', kx]: at the samples
        self.byy = (self.by[:, :, None] * self.by[:, None, :]).reshape(len(self.by), ky * ky)  # [h', ky ky]
        self.bxx = (self.bx[:, :, None] * self.bx[:, None, :]).reshape(len(self.bx), kx * kx)  # [w', kx kx]
        dy = np.diff(np.eye(ky), 2, axis=0)  # second differences along y and along x of the control grid
        dx = np.diff(np.eye(kx), 2, axis=0)
        D = np.concatenate([np.kron(dy, np.eye(kx)), np.kron(np.eye(ky), dx)])  # [M, K]
        self.penalty = D.T @ D  # [K, K]
        for a in (self.By, self.Bx, self.by, self.bx, self.byy, self.bxx, self.penalty):
            a.flags.writeable = False  # shared between callers by spline_design's cache

    def samples(self, field: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The field's ``(h', w', 2)`` samples (non-finite ones at weight 0) and their ``(h', w')`` weights."""
        st = self.step
        f = field[::st, ::st].astype(np.float64)
        w0 = weight[::st, ::st].astype(np.float64)
        ok = np.isfinite(f).all(axis=-1)
        return np.where(ok[..., None], f, 0.0), np.where(ok, w0, 0.0)

    def at_samples(self, c: np.ndarray) -> np.ndarray:
        """The spline of control values ``c`` ``(ky, kx, 2)`` at the samples, ``(h', w', 2)``."""
        return np.stack([self.by @ c[..., i] @ self.bx.T for i in range(2)], axis=-1)

    def solve(
        self, f: np.ndarray, w0: np.ndarray, robust: float, ridge: float, iterations: int, bend: float = 0.0
    ) -> np.ndarray:
        """Control values ``(ky, kx, 2)``: iteratively reweighted (Cauchy) least squares with ridge and
        bend penalties."""
        kx, ky = self.grid
        reg = ridge * np.eye(kx * ky) + bend * self.penalty
        fit = np.zeros_like(f)
        for it in range(iterations):
            wi = w0 if it == 0 else w0 / (1 + (_lengths(f - fit) / robust) ** 2)  # [h', w']
            normal = (self.byy.T @ (wi @ self.bxx)).reshape(ky, ky, kx, kx)  # [i, k, j, l]
            normal = normal.transpose(0, 2, 1, 3).reshape(kx * ky, kx * ky)  # rows (i, j), columns (k, l)
            rhs = np.stack([self.by.T @ (f[..., i] * wi) @ self.bx for i in range(2)], axis=-1)  # [ky, kx, 2]
            c = solve_spd(normal + reg, rhs.reshape(kx * ky, 2)).reshape(ky, kx, 2)
            fit = self.at_samples(c)
        return c

    def evaluate(self, c: np.ndarray) -> np.ndarray:
        """The spline of control values ``c`` at every pixel, float32 ``(H, W, 2)``."""
        return np.stack([self.By @ c[..., i] @ self.Bx.T for i in range(2)], axis=-1).astype(np.float32)


def _lengths(v: np.ndarray) -> np.ndarray:
    """The length of each 2-vector of ``v`` ``(..., 2)``: ``np.linalg.norm(v, axis=-1)`` to the bit, a fifth of
    its time (numpy reduces a last axis of two slowly)."""
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1])


def near_data_ramp(weight: np.ndarray, grid: tuple[int, int], fade: tuple[float, float]) -> np.ndarray:
    """How much data a fine spline on ``grid`` has near each pixel, float32 ``(H, W)`` in [0, 1]: a ramp
    over ``fade`` of ``weight``'s density within about half a knot spacing (where a spline beyond its
    data would only extrapolate its slopes)."""
    h, w = weight.shape[:2]
    sigma = 0.5 * max(h / (grid[1] - 3), w / (grid[0] - 3))  # half a knot spacing, px
    return ramp(gaussian(weight.astype(np.float32), sigma), *fade)


def fit_detail(
    remainder: np.ndarray,
    weight: np.ndarray,
    grid: tuple[int, int],
    bends: tuple[float, ...],
    step: int,
    robust: float,
    block: int = 32,
    gain: float = 0.05,
    ridge: float = 1e-3,
    iterations: int = 3,
    fade: tuple[float, float] = (0.05, 0.3),
    near_data: Callable[[], np.ndarray] | None = None,
) -> tuple[np.ndarray, float | None]:
    """Surface detail finer than the coarse spline (a short-period bend), only where the data carry it.

    ``remainder`` (what the coarse spline left of the DIS residual) is fitted by a P-spline on the
    fine ``grid`` at each penalty weight in ``bends``; two-fold cross-validation on a checkerboard of
    ``block`` px blocks (fit on one colour, score the other: DIS's errors are correlated over its
    patches, so neighbouring pixels cannot vouch for each other) scores each against leaving the
    remainder alone. The winner must lower the held-out robust loss (texture-weighted Cauchy) by
    ``gain``; otherwise no detail is added. The detail fades out where ``weight`` has no data within
    about half a knot spacing (a P-spline extrapolates its slopes; beyond the data that is a guess): it is
    weighted by a ramp over ``fade`` of the texture density within that distance. ``ridge`` and
    ``iterations`` are the solves' (:func:`fit_bspline`); ``near_data``: that ramp
    (:func:`near_data_ramp` of ``weight``, ``grid`` and ``fade``) from a caller that keeps it, asked for
    only when the detail wins.

    Returns:
        ``(detail, bend)``: float32 ``(H, W, 2)`` (zeros when nothing wins) and the chosen penalty
        (None: none).
    """
    h, w = remainder.shape[:2]
    design = spline_design(h, w, tuple(grid), step)
    f, w0 = design.samples(remainder, weight)
    y, x = np.mgrid[0:h:step, 0:w:step]
    colour = ((y // block) + (x // block)) % 2 > 0  # [h', w']

    def held_out(pred: np.ndarray, mask: np.ndarray) -> float:
        e = _lengths(f - pred)
        return float((w0 * mask * np.log1p((e / robust) ** 2)).sum())

    with one_blas_thread():
        losses = {None: held_out(0 * f, colour) + held_out(0 * f, ~colour)}
        for bend in bends:
            fits = [
                design.at_samples(design.solve(f, w0 * ~m, robust, ridge, iterations, bend)) for m in (colour, ~colour)
            ]
            losses[bend] = held_out(fits[0], colour) + held_out(fits[1], ~colour)
        best = min(losses, key=losses.get)
        if best is None or losses[best] > (1 - gain) * losses[None]:
            return np.zeros_like(remainder, dtype=np.float32), None
    near = near_data() if near_data is not None else near_data_ramp(weight, grid, fade)
    with one_blas_thread():
        detail = design.evaluate(design.solve(f, w0, robust, ridge, iterations, best))
    return detail * near[..., None], best
