"""The warp map and its mesh (projreg.inference.warpmaps, warpmesh): values against the STMap formula, the
coverage of compensate, the identity for a pair not registered, and the mesh's interpolation measured
independently of the code under test."""

import doctest
import itertools

import numpy as np
import pytest

from projreg.errors import ProjregError
from projreg.inference import warpmaps, warpmesh
from projreg.inference.compensate import content_mask, prewarp, shown_pixels
from projreg.inference.warpmaps import OUTSIDE, warp_map
from projreg.inference.warpmesh import drawn_map, grid_mesh, mesh_error, obj_text

from .warpcases import CAMERA, H, W, bent_homography, parse_obj, rasterise


def test_the_uv_of_a_pixel_is_the_stmap_formula_at_the_camera_position():
    flow = bent_homography()
    m = warp_map(flow, camera_size=CAMERA)
    for y, x in [(0, 0), (10, 20), (30, 41), (H - 1, 5)]:
        if m.shown[y, x]:
            cx, cy = x + float(flow[y, x, 0]), y + float(flow[y, x, 1])
            u, v = (cx + 0.5) / CAMERA[1], 1 - (cy + 0.5) / CAMERA[0]
            np.testing.assert_allclose(m.uv[y, x], [u, v], rtol=0, atol=1e-7)
    assert m.shown[10, 20] and m.shown[30, 41] and not m.shown.all()  # part of the frame lands outside
    assert (m.uv[~m.shown] == OUTSIDE).all()
    rgba = m.stmap()
    assert rgba.dtype == np.float32 and rgba.shape == (H, W, 4)
    assert (rgba[..., 2] == 0).all() and (rgba[..., 3] == m.shown).all()
    assert (rgba[m.shown][:, :2] >= 0).all() and (rgba[m.shown][:, :2] <= 1).all()  # on the content


@pytest.mark.parametrize(
    ("coverage", "min_confidence"), [("complete", 0.0), ("complete", 0.5), ("claimed", 0.0), ("claimed", 0.9)]
)
def test_the_pixels_shown_are_compensates(coverage, min_confidence):
    flow = bent_homography()
    claimed = np.zeros((H, W), bool)
    claimed[5:40, 10:50] = True
    confidence = np.tile(np.linspace(1, 0, W, dtype=np.float32), (H, 1))
    policy = {"claimed": claimed, "confidence": confidence, "coverage": coverage, "min_confidence": min_confidence}
    m = warp_map(flow, **policy, camera_size=CAMERA)
    shown = shown_pixels(claimed, confidence, coverage, min_confidence)
    np.testing.assert_array_equal(m.shown, content_mask(flow, shown, True, coverage, CAMERA))
    image = prewarp(np.full((*CAMERA, 3), 200, np.uint8), flow, **policy, camera_size=CAMERA)
    np.testing.assert_array_equal(m.shown, image[..., 0] == 200)


def test_a_pair_not_registered_is_the_identity_map():
    flow = bent_homography()
    m = warp_map(flow, claimed=np.zeros((H, W), bool), registered=False, camera_size=CAMERA)
    y, x = np.mgrid[0:H, 0:W]
    assert m.shown.all()
    np.testing.assert_allclose(m.uv[..., 0], (x + 0.5) / W, atol=1e-7)
    np.testing.assert_allclose(m.uv[..., 1], 1 - (y + 0.5) / H, atol=1e-7)
    with pytest.raises(ProjregError, match="no projector pixel shows content"):  # claimed: nothing to show
        warp_map(flow, claimed=np.zeros((H, W), bool), registered=False, coverage="claimed", camera_size=CAMERA)


def test_remap_maps_are_the_positions_in_content_pixels_clamped_to_the_outer_centres():
    flow = bent_homography()
    m = warp_map(flow, camera_size=CAMERA)
    map_x, map_y = m.remap_maps((120, 160))  # content twice the camera frame's size
    y, x = np.mgrid[0:H, 0:W]
    want_x = np.clip((x + flow[..., 0] + 0.5) * 2 - 0.5, 0, 159)
    want_y = np.clip((y + flow[..., 1] + 0.5) * 2 - 0.5, 0, 119)
    np.testing.assert_allclose(map_x[m.shown], want_x[m.shown], atol=1e-4)
    np.testing.assert_allclose(map_y[m.shown], want_y[m.shown], atol=1e-4)
    assert (map_x[~m.shown] < -1).all()  # a frame off the content: black under cv2.remap's constant border


@pytest.mark.parametrize(
    "size", [None, (96,), "96x128", (0, 0), (-5, -5), (float("nan"),) * 2, (96.5, 128.5), (True, 8)]
)
def test_remap_maps_refuse_a_content_size_that_is_not_two_positive_integers(size):
    m = warp_map(bent_homography(), camera_size=CAMERA)
    with pytest.raises(ProjregError, match=r"^content_size: expected two integers in 1..16384"):
        m.remap_maps(size)  # (0, 0) and (nan, nan) returned nonsense maps, None raised a raw TypeError


def test_remap_maps_take_numpy_integers():
    m = warp_map(bent_homography(), camera_size=CAMERA)
    for a, b in zip(m.remap_maps(np.array([120, 160])), m.remap_maps((120, 160)), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("step", [5, 8, 16])
def test_the_reported_interpolation_error_is_the_rendered_meshs(step):
    m = warp_map(bent_homography(), camera_size=CAMERA)
    mesh = grid_mesh(m, step)
    v, vt, triangles = parse_obj(obj_text(mesh, ["a test"]))
    assert (v[:, 2] == 0).all() and len(triangles) == 2 * mesh.faces.sum()
    drawn = rasterise(v, vt, triangles, (H, W))
    covered = ~np.isnan(drawn[..., 0])
    both = covered & m.shown
    d = (drawn - m.uv) * (CAMERA[1], CAMERA[0])
    err = np.hypot(d[..., 0], d[..., 1])[both]
    stats = mesh_error(m, mesh)
    assert err.max() > 0.01  # the bend is not linear: the test measures something
    assert stats["error_mean"] == pytest.approx(err.mean(), abs=1e-5)
    assert stats["error_max"] == pytest.approx(err.max(), abs=1e-5)
    assert stats["covered"] == pytest.approx(both.sum() / m.shown.sum())
    np.testing.assert_array_equal(drawn_map(mesh).shown, covered)


def test_faces_only_where_every_corner_shows_content_counter_clockwise_on_screen():
    m = warp_map(bent_homography(), camera_size=CAMERA)
    mesh = grid_mesh(m, 8)
    v, vt, triangles = parse_obj(obj_text(mesh, []))
    corners = v[triangles][..., :2].astype(int)  # [F, 3, 2] (x, y)
    assert m.shown[corners[..., 1], corners[..., 0]].all()
    np.testing.assert_allclose(vt, m.uv[v[:, 1].astype(int), v[:, 0].astype(int)], atol=1e-7)
    # every cell whose four corners show content is drawn, counted without the code under test
    xs, ys = list(range(0, W, 8)) + [W - 1], list(range(0, H, 8)) + [H - 1]
    cells = sum(
        m.shown[[y0, y0, y1, y1], [x0, x1, x0, x1]].all()
        for y0, y1 in itertools.pairwise(ys)
        for x0, x1 in itertools.pairwise(xs)
    )
    assert 0 < cells == len(triangles) // 2 < (len(xs) - 1) * (len(ys) - 1)
    a, b, c = (corners[:, i].astype(float) for i in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    assert (cross < 0).all()  # clockwise in y-down coordinates: counter-clockwise as the frame shows on screen


def test_step_one_draws_the_map_exactly():
    m = warp_map(bent_homography(), camera_size=CAMERA)
    mesh = grid_mesh(m, 1)
    drawn = drawn_map(mesh)
    assert (drawn.shown <= m.shown).all() and drawn.shown.sum() >= 0.97 * m.shown.sum()
    np.testing.assert_array_equal(drawn.uv[drawn.shown], m.uv[drawn.shown])
    assert mesh_error(m, mesh)["error_max"] == 0


def test_the_last_row_and_column_are_always_vertices():
    mesh = grid_mesh(warp_map(np.zeros((H, W, 2), np.float32)), 10)
    assert mesh.xs.tolist() == [0, 10, 20, 30, 40, 50, 60, 63] and mesh.ys.tolist() == [0, 10, 20, 30, 40, 47]
    assert mesh.faces.all() and mesh_error(warp_map(np.zeros((H, W, 2), np.float32)), mesh)["covered"] == 1


@pytest.mark.parametrize("step", [0, -3, H, 2.5, True])
def test_a_step_out_of_the_grid_is_refused_naming_the_option(step):
    with pytest.raises(ProjregError, match=r"^--step .*: expected an integer in 1\.\.47"):
        grid_mesh(warp_map(np.zeros((H, W, 2), np.float32)), step)


def test_the_docstring_examples_run():
    assert doctest.testmod(warpmaps).failed == 0 and doctest.testmod(warpmesh).failed == 0
