"""The normal equations summed over the basis' local support equal the dense sum over every pixel."""

import numpy as np
import pytest

from projreg.geometry.gram import gram
from projreg.geometry.splines import bspline_basis


def dense(products, grid):
    """``sum_p product(p) B_i(y) B_j(x) B_k(y) B_l(x)`` from the full basis, rows and columns (y, x)."""
    n, h, w = products.shape
    kx, ky = grid
    By, Bx = bspline_basis(h, ky), bspline_basis(w, kx)
    out = np.einsum("nyx,yi,xj,yk,xl->nijkl", products, By, Bx, By, Bx)
    return out.reshape(n, kx * ky, kx * ky)


@pytest.mark.parametrize("size", [(48, 64), (37, 50), (9, 13)])
@pytest.mark.parametrize("grid", [(4, 4), (6, 5), (14, 11)])
def test_blocks_equal_the_dense_sum(size, grid):
    products = np.random.default_rng(sum(size) + sum(grid)).normal(size=(3, *size))
    got = gram(*size, grid).blocks(products)
    want = dense(products, grid)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_blocks_are_symmetric_and_positive_for_positive_weights():
    products = np.random.default_rng(3).uniform(0.1, 1.0, (1, 40, 60))
    (block,) = gram(40, 60, (6, 5)).blocks(products)
    np.testing.assert_allclose(block, block.T, rtol=1e-12, atol=1e-14)
    assert np.linalg.eigvalsh(block).min() > 0
