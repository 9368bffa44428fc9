"""The smooth surface models: the B-spline basis and fit, its separable normal equations, the detail P-spline."""

import numpy as np

from projreg.geometry.splines import SplineDesign, bspline_basis, fit_bspline, fit_detail


def test_bspline_basis_is_a_partition_of_unity_and_reproduces_linear_fields():
    B = bspline_basis(97, 7)  # [97, 7]
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-12)
    assert (B >= 0).all()
    h, w = 60, 80
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    field = np.stack([0.5 + 0.03 * x - 0.02 * y, -1.0 + 0.01 * x * 0 + 0.04 * y], axis=-1)  # affine: in the span
    fit = fit_bspline(field, np.ones((h, w)), (6, 5), step=2, ridge=1e-9)
    np.testing.assert_allclose(fit, field, atol=1e-4)


def test_bspline_fit_ignores_outliers_and_zero_weight_pixels():
    h, w = 64, 96
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    field = np.stack([1 + 0.02 * x, 2 - 0.01 * y], axis=-1)
    noisy = field.copy()
    rng = np.random.default_rng(0)
    bad = rng.random((h, w)) < 0.15
    noisy[bad] += rng.uniform(-20, 20, (int(bad.sum()), 2))
    weight = np.ones((h, w))
    weight[:, :10] = 0
    noisy[:, :10] = 1e3  # no weight: must not matter at all
    fit = fit_bspline(noisy, weight, (6, 5), step=1, iterations=6)
    assert np.abs(fit - field).max() < 0.1, np.abs(fit - field).max()


def test_separable_normal_equations_match_the_dense_design_matrix():
    h, w, step, grid = 50, 70, 3, (7, 5)
    rng = np.random.default_rng(3)
    field, weight = rng.normal(0, 1, (h, w, 2)), rng.random((h, w))
    design = SplineDesign(h, w, grid, step)
    f, w0 = design.samples(field, weight)
    A = np.einsum("yi,xj->yxij", design.by, design.bx).reshape(-1, grid[0] * grid[1])  # [N, K], dense
    reg = 0.1 * np.eye(A.shape[1]) + 2.0 * design.penalty
    dense = np.linalg.solve(A.T @ (A * w0.reshape(-1, 1)) + reg, A.T @ (f.reshape(-1, 2) * w0.reshape(-1, 1)))
    c = design.solve(f, w0, robust=1.0, ridge=0.1, iterations=1, bend=2.0)
    np.testing.assert_allclose(c.reshape(-1, 2), dense, atol=1e-9)
    np.testing.assert_allclose(design.at_samples(c).reshape(-1, 2), A @ dense, atol=1e-9)


def test_fit_detail_adds_a_short_bend_and_leaves_noise_alone():
    h, w = 192, 256
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    rng = np.random.default_rng(4)
    wave = np.stack([3 * np.sin(2 * np.pi * y / 90), 2 * np.sin(2 * np.pi * x / 110)], axis=-1)  # too short for 6 x 5
    noise = rng.normal(0, 1.0, (h, w, 2)).astype(np.float32)
    weight = np.ones((h, w), np.float32)
    weight[:, 180:] = 0  # no data on the right: the detail must stay bounded there (ridge + bend)
    detail, bend = fit_detail(wave + noise, weight, (14, 11), (0.3, 3.0, 30.0), 2, 1.0)
    assert bend is not None
    err = np.linalg.norm(detail - wave, axis=-1)
    assert err[:, 20:160].mean() < 0.4, err[:, 20:160].mean()  # the wave, to a fraction of the noise
    assert np.linalg.norm(detail, axis=-1)[:, 220:].max() < 4.0
    nothing, bend = fit_detail(noise, weight, (14, 11), (0.3, 3.0, 30.0), 2, 1.0)
    assert bend is None and not nothing.any()  # pure noise: cross-validation keeps the coarse fit
