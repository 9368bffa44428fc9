"""Direct photometric alignment: a flow ``base + spline`` whose B-spline control values minimise the
robust difference between the projected image and the captured one warped back, by Gauss-Newton over an
image pyramid.

Each step linearises the warped image in the control values (the gradient is the mean of the projected
image's and the warped image's, as in efficient second-order minimisation), weights the pixels by their
texture and a Cauchy function of their residual (scale: the residuals' median absolute deviation), and
solves the normal equations with a second-difference penalty on the control grid (a P-spline: where the
images carry no texture the surface is bridged smoothly) and a small ridge. The per-pixel work is one
fused pass (:mod:`~projreg.geometry.linearised`); the normal equations are summed span by span over the
basis' local support (:mod:`~projreg.geometry.gram`).
Coarse levels see displacements of several pixels; the finest closes the last tenth of a pixel.

Convention: gray images float32 ``(H, W)`` on the projected grid (projected) and the captured grid
(captured, any size); flows float32 ``(H, W, 2)``, forward, projected -> captured, pixels; control
values ``(ky, kx, 2)`` in pixels of the finest level.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache

import cv2
import numpy as np

from .gram import gram
from .linalg import one_blas_thread, solve_spd
from .linearised import TEXTURED, linearise
from .splines import bspline_basis

TRUST_STRIDE = 4  # px of a level: a step's displacement of the textured pixels is read on every 4th pixel each way
# (a spline whose knots lie 30 px or more apart is smooth at that scale)


class Stopped(Exception):
    """An alignment stopped by its caller (``stop``) before its steps were spent: its answer is not wanted."""


@dataclass(frozen=True)
class Level:
    """One pyramid level of a pair: the projected and captured images, the projected image's gradient and
    the texture weight, at ``scale`` of the finest level."""

    scale: float
    projected: np.ndarray
    captured: np.ndarray
    gradient: tuple[np.ndarray, np.ndarray]
    weight: np.ndarray

    @cached_property
    def textured(self) -> np.ndarray:
        """Bool ``(h', w')``: the textured pixels (weight over ``TEXTURED``) of every ``TRUST_STRIDE``-th row
        and column, where a step's displacement is read (``align(on_texture=True)``)."""
        return self.weight[::TRUST_STRIDE, ::TRUST_STRIDE] > TEXTURED


def pyramid(
    projected: np.ndarray, captured: np.ndarray, weight: np.ndarray, factors: tuple[int, ...]
) -> dict[int, Level]:
    """The levels of a pair at each of ``factors`` (1: the images themselves, 2: half size, ...), by factor.

    ``projected``/``captured``: gray images (any dtype; float32 internally); ``weight``: the projected
    image's texture weight in [0, 1]."""
    out = {}
    for f in factors:
        p, c, wt = (_shrunk(a.astype(np.float32), f) for a in (projected, captured, weight))
        out[f] = Level(1.0 / f, p, c, _gradient(p), wt)
    return out


def _shrunk(image: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return image
    h, w = image.shape[:2]
    return cv2.resize(image, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)


def _gradient(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences (Sobel / 8: the slope in grey levels per pixel), x and y."""
    return cv2.Sobel(image, cv2.CV_32F, 1, 0) / 8, cv2.Sobel(image, cv2.CV_32F, 0, 1) / 8


@lru_cache(maxsize=16)
def _basis(h: int, w: int, grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``By`` ``(h, ky)`` and ``Bx`` ``(w, kx)``."""
    kx, ky = grid
    return bspline_basis(h, ky), bspline_basis(w, kx)


@lru_cache(maxsize=8)
def _penalty(grid: tuple[int, int]) -> np.ndarray:
    """Second differences of the control grid along y and along x, ``D^T D`` ``(K, K)``."""
    kx, ky = grid
    dy, dx = np.diff(np.eye(ky), 2, axis=0), np.diff(np.eye(kx), 2, axis=0)
    D = np.concatenate([np.kron(dy, np.eye(kx)), np.kron(np.eye(ky), dx)])
    return D.T @ D


def spline_field(control: np.ndarray, h: int, w: int) -> np.ndarray:
    """The B-spline of ``control`` ``(ky, kx, 2)`` on an ``h x w`` grid, float32 ``(h, w, 2)``."""
    ky, kx = control.shape[:2]
    By, Bx = _basis(h, w, (kx, ky))
    return np.stack([By @ control[..., i] @ Bx.T for i in range(2)], axis=-1).astype(np.float32)


def align(
    levels: dict[int, Level],
    base: np.ndarray,
    grid: tuple[int, int],
    iterations: dict[int, int],
    bend: float,
    ridge: float,
    max_step: float = 1.0,
    tolerance: float = 0.0,
    stop: Callable[[], bool] | None = None,
    on_texture: bool = False,
    cauchy: float = 1.0,
    last: tuple[int, float] = (0, 1.0),
) -> np.ndarray:
    """The flow ``base + spline`` aligning the pair of ``levels`` (:func:`pyramid`), coarse to fine.

    Args:
        levels: the pair's pyramid, by factor.
        base: float32 ``(H, W, 2)`` start flow at the finest level (a homography's, or an earlier answer).
        grid: the spline's control points ``(kx, ky)``.
        iterations: Gauss-Newton steps at each factor, coarsest first (factors without steps are skipped).
        bend: second-difference penalty, relative to the mean diagonal of the normal equations.
        ridge: pull of every control value towards 0, relative likewise.
        max_step: the most one step moves a control value, in pixels of its level (a step that would
            move one farther is shortened): the linearisation holds about a pixel.
        tolerance: a level stops before its steps are spent once a step moves no control value farther
            than this, in pixels of its level (0: every step is taken).
        stop: asked before each step; once it says True the alignment raises :class:`Stopped` (a caller that
            no longer wants the answer frees the thread within a step).
        on_texture: ``max_step`` bounds how far a step moves the textured pixels (read on a grid, ``TRUST_STRIDE``)
            instead of how far it moves any control value: a control value over a flat region, which the
            data do not constrain, no longer shortens the step for all.
        cauchy: the robust weights' Cauchy scale, in standard deviations of the level's residuals.
        last: the finest level's last ``last[0]`` steps (of its ``iterations``) weigh at ``last[1]``
            standard deviations instead (graduated robustness: a wide Cauchy converges in few steps, a
            narrow one lets go of structured outliers, occluders or reflectance edges, that pulled it).
            A level stopped by ``tolerance`` still takes these steps.

    Returns:
        float32 ``(H, W, 2)``: ``base`` plus the fitted spline.
    """
    kx, ky = grid
    control = np.zeros((ky, kx, 2))
    reg = bend * _penalty(grid) + ridge * np.eye(kx * ky)
    for factor in sorted(iterations, reverse=True):
        level = levels[factor]
        h, w = level.projected.shape
        start = base if factor == 1 else cv2.resize(base, (w, h), interpolation=cv2.INTER_AREA) * level.scale
        n = iterations[factor]
        narrow = min(last[0], n) if factor == 1 else 0
        for count, width in ((n - narrow, cauchy), (narrow, last[1])):
            for _ in range(count):
                if stop is not None and stop():
                    raise Stopped
                delta = _step(level, start, control, grid, reg, max_step, on_texture, width)
                control = control + delta
                if float(np.abs(delta).max()) * level.scale < tolerance:  # converged at this level and width
                    break
    return base + spline_field(control, *base.shape[:2])


def _step(
    level: Level,
    start: np.ndarray,
    control: np.ndarray,
    grid: tuple[int, int],
    reg: np.ndarray,
    max_step: float,
    on_texture: bool = False,
    cauchy: float = 1.0,
) -> np.ndarray:
    """One robust Gauss-Newton update of the control values (module docstring), the Cauchy at ``cauchy``
    standard deviations of the residuals."""
    kx, ky = grid
    k = kx * ky
    h, w = level.projected.shape
    By, Bx = _basis(h, w, grid)
    s = level.scale
    columns = np.stack([control[..., i] @ Bx.T for i in range(2)]) * s  # [2, ky, w], this level's pixels
    products = np.empty((5, h, w))  # [5, h, w]: w gx gx, w gx gy, w gy gy, w gx r, w gy r
    linearise(
        level.projected, level.captured, level.gradient, level.weight, start, By, columns, 0.5 * s, products, cauchy
    )
    with one_blas_thread():
        blocks = gram(h, w, grid).blocks(products[:3])  # [3, k, k]
        normal = np.block([[blocks[0], blocks[1]], [blocks[1].T, blocks[2]]])
        rhs = np.concatenate([(By.T @ products[i] @ Bx).ravel() for i in (3, 4)])
    current = np.concatenate([control[..., 0].ravel(), control[..., 1].ravel()])
    penalty = np.kron(np.eye(2), reg * (np.trace(normal) / (2 * k) + 1e-9))
    delta = solve_spd(normal + penalty, -rhs - penalty @ current)
    step = np.stack([delta[:k].reshape(ky, kx), delta[k:].reshape(ky, kx)], axis=-1)  # [ky, kx, 2]
    reach = _reach(level, step, By, Bx) if on_texture else float(np.abs(delta).max())
    reach *= s  # the largest move, in this level's pixels
    return step * (max_step / reach) if reach > max_step else step


def _reach(level: Level, step: np.ndarray, By: np.ndarray, Bx: np.ndarray) -> float:
    """The farthest a spline step ``(ky, kx, 2)`` moves a textured pixel of ``level`` (:attr:`Level.textured`),
    in control units; the farthest control value's move where the level has no texture."""
    mask = level.textured
    if not mask.any():
        return float(np.abs(step).max())
    rows, cols = By[::TRUST_STRIDE], Bx[::TRUST_STRIDE]
    u, v = (rows @ step[..., i] @ cols.T for i in range(2))  # [h', w'] each
    return float(np.sqrt((u * u + v * v)[mask].max()))
