"""The fits' linear algebra: normal equations solved by Cholesky, LU where that cannot factor."""

import numpy as np

from projreg.geometry.linalg import solve_spd


def test_solve_spd_solves_normal_equations_and_falls_back_on_an_indefinite_matrix():
    """Cholesky on a positive definite matrix (a fine grid's 308 unknowns, one or two right-hand sides);
    LU where the matrix is symmetric but indefinite (Cholesky cannot factor it)."""
    rng = np.random.default_rng(0)
    m = rng.normal(size=(308, 900))
    a = m @ m.T + 1e-3 * np.eye(308)
    for b in (rng.normal(size=308), rng.normal(size=(308, 2))):
        x = solve_spd(a, b)
        assert x.shape == b.shape and np.abs(a @ x - b).max() < 1e-9 * np.abs(b).max() * np.abs(a).max()
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])
    np.testing.assert_allclose(solve_spd(indefinite, np.array([3.0, 3.0])), [1.0, 1.0])
