"""Dense linear algebra the fits share: small products on one BLAS thread, and the solve of normal
equations (symmetric positive definite: a ridge is always added).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import wraps

import cv2
import numpy as np
from threadpoolctl import ThreadpoolController

_BLAS = ThreadpoolController()


def one_blas_thread():
    """A context with one BLAS thread: the spline's products are small, and a second thread contending
    with torch's OpenMP workers (or another process) made one fit take 1.5-4 s instead of 50 ms on the
    2-core VM."""
    return _BLAS.limit(limits=1, user_api="blas")


def on_one_blas_thread(fn: Callable) -> Callable:
    """``fn`` run in :func:`one_blas_thread`: for work that has threads of its own, beside which BLAS's
    would only contend for the cores (waiting BLAS threads spin: with the refinement on one thread, its
    small solves stalled for tens of milliseconds)."""

    @wraps(fn)
    def run(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return run


def solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The solution ``x`` of ``a x = b`` for a symmetric positive definite ``a`` (normal equations with a
    ridge): by Cholesky (OpenCV's, about half the time of NumPy's LU on the 308 unknowns of a fine grid's
    step), by LU where the factorisation finds ``a`` not positive definite. ``b``: ``(n,)`` or ``(n, m)``."""
    rhs = np.asarray(b, np.float64)
    ok, x = cv2.solve(np.asarray(a, np.float64), rhs.reshape(len(rhs), -1), flags=cv2.DECOMP_CHOLESKY)
    return x.reshape(rhs.shape) if ok else np.linalg.solve(a, b)
