import cv2
import numpy as np
import pytest

from projsynth.sim.lens import Lens, distort, pixels_to_rays, project_points, undistort

DIST = (-0.21, 0.04, 0.0015, -0.002, 0.01)


def test_distort_matches_opencv_projection():
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.4, 0.4, (200, 2)), np.ones(200)]
    K = np.array([[500.0, 0, 255.5], [0, 510.0, 191.5], [0, 0, 1]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, np.array(DIST))
    lens = Lens(500.0, 510.0, 255.5, 191.5, DIST)
    u, v, ok = project_points(lens, pts.T)
    assert ok.all()
    np.testing.assert_allclose(np.c_[u, v], ref[:, 0], atol=1e-9)


@pytest.mark.parametrize("dist", [DIST, (0.15, -0.02, -0.003, 0.002, 0.0), (0.0, 0.0, 0.004, 0.0, 0.0)])
def test_undistort_inverts_distort_below_1e6_px(dist):
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-0.45, 0.45, (2, 5000))
    xd, yd = distort(x, y, dist)
    xu, yu, ok = undistort(xd, yd, dist, scale=500.0)
    assert ok.all()
    assert np.abs(np.r_[xu - x, yu - y]).max() * 500 < 1e-6


def test_pixels_to_rays_round_trip():
    lens = Lens(480.0, 480.0, 250.0, 190.0, DIST, 512, 384)
    u, v = np.meshgrid(np.arange(0, 512, 7.3), np.arange(0, 384, 5.1))
    dirs, ok = pixels_to_rays(lens, u.ravel(), v.ravel())
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=0), 1.0, atol=1e-12)
    pu, pv, pok = project_points(lens, dirs * 3.7)
    assert ok.all() and pok.all()
    assert max(np.abs(pu - u.ravel()).max(), np.abs(pv - v.ravel()).max()) < 1e-6


def test_fold_radius_marks_folded_points_invalid():
    strong = Lens(300.0, 300.0, 0.0, 0.0, (-0.6, 0.0, 0.0, 0.0, 0.0))
    assert strong.max_radius < 1.0  # r(1 - 0.6 r^2) has a maximum at r = 0.745
    _, _, ok = project_points(strong, np.array([[0.1, 0.9], [0.0, 0.0], [1.0, 1.0]]))
    assert ok.tolist() == [True, False]


def test_array_functions_reject_mismatched_shapes():
    lens = Lens(480.0, 480.0, 250.0, 190.0, DIST, 512, 384)
    with pytest.raises(ValueError, match="as many u as v"):
        pixels_to_rays(lens, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match=r"\(3, N\)"):
        project_points(lens, np.zeros((2, 4)))
    with pytest.raises(ValueError, match="5 coefficients"):
        distort(np.zeros(2), np.zeros(2), (0.1, 0.0))
