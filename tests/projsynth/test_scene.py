import numpy as np
import pytest

from projsynth.lens import Lens
from projsynth.rig import make_scene
from projsynth.scene import OCCLUDED, Scene, backward, forward, look_at, pixel_grid, rotation_about
from projsynth.surface import Surface, intersect
from projsynth.transforms import FAMILIES, builtin_table

H, W = 96, 128


def _config(family, severity):
    return next(c for c in builtin_table().configs if c.family == family and c.severity == severity)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("severity", [1, 4])
def test_round_trip_closes_below_001_px(family, severity):
    for seed in range(3):
        cfg = _config(family, severity)
        scene, _ = make_scene(family, cfg.geometry, np.random.default_rng(seed), (H, W))
        grid = pixel_grid(H, W)
        fm = forward(scene, grid)
        assert fm.valid.mean() > 0.3
        back, lit = backward(scene, fm.uv[:, fm.valid])
        assert lit.mean() > 0.99  # a valid point is lit where the camera sees it
        err = np.hypot(*(back[:, lit] - grid[:, fm.valid][:, lit]))
        assert err.max() < 0.01, (family, severity, seed, err.max())


def _simple_scene(kind, params, baseline_deg=20.0):
    f = W / (2 * np.tan(np.radians(25)))
    lens = Lens(f, f, (W - 1) / 2, (H - 1) / 2, (0.0,) * 5, W, H)
    target = np.array([0.0, 0.0, 1.0])
    C = target + rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(baseline_deg)) @ -target
    surface = Surface(kind, np.eye(3), target, params)
    return Scene(lens, lens, look_at(C, target, (0.0, 0.0), 0.0, lens), C, surface)


def test_plane_flow_is_a_homography():
    scene = _simple_scene("plane", {})
    grid = pixel_grid(H, W)
    fm = forward(scene, grid)
    src, dst = grid[:, fm.valid].T, fm.uv[:, fm.valid].T
    A = []
    for (x, y), (u, v) in zip(src[::37], dst[::37], strict=True):
        A += [[x, y, 1, 0, 0, 0, -u * x, -u * y, -u], [0, 0, 0, x, y, 1, -v * x, -v * y, -v]]
    Hm = np.linalg.svd(np.array(A))[2][-1].reshape(3, 3)
    p = Hm @ np.c_[src, np.ones(len(src))].T
    assert np.abs(p[:2] / p[2] - dst.T).max() < 1e-6


def test_convex_sphere_occludes_and_occluded_points_are_hidden():
    scene = _simple_scene("sphere_convex", {"radius": 0.35}, baseline_deg=35.0)
    grid = pixel_grid(H, W)
    fm = forward(scene, grid)
    occluded = (fm.reason & OCCLUDED) > 0
    assert occluded.sum() > 20
    # the camera's ray towards an occluded point meets the sphere strictly before it
    dirs, _ = __import__("projsynth.lens", fromlist=["pixels_to_rays"]).pixels_to_rays(
        scene.projector, grid[0, occluded], grid[1, occluded])
    t, hit = intersect(scene.surface, np.zeros((3, 1)), dirs)
    X = dirs * t
    ray = X - scene.C[:, None]
    dist = np.linalg.norm(ray, axis=0)
    tc, hitc = intersect(scene.surface, scene.C[:, None], ray / dist)
    assert hit.all() and hitc.all() and (tc < dist - 1e-6).all()


def test_heightfield_hits_lie_on_the_surface():
    params = {"waves": [[0.04, 6.0, 2.0, 0.3]]}
    scene = _simple_scene("wave", params)
    grid = pixel_grid(H, W)
    from projsynth.lens import pixels_to_rays

    dirs, _ = pixels_to_rays(scene.projector, grid[0], grid[1])
    t, hit = intersect(scene.surface, np.zeros((3, 1)), dirs)
    X = dirs[:, hit] * t[hit] - scene.surface.origin[:, None]
    h = 0.04 * np.sin(6.0 * X[0] + 2.0 * X[1] + 0.3)
    assert hit.all() and np.abs(X[2] - h).max() < 1e-9


def test_plane_seen_from_behind_is_not_visible():
    scene = _simple_scene("plane", {}, baseline_deg=150.0)  # the camera looks at the plane's back
    fm = forward(scene, pixel_grid(H, W))
    _, lit = backward(scene, pixel_grid(H, W))
    assert ((fm.reason & OCCLUDED) > 0).sum() > 1000  # lit by the projector, hidden from the camera
    assert not fm.valid.any() and not lit.any()


@pytest.mark.parametrize("family", ["lens", "sphere_convex", "wave", "bumps"])
def test_maps_do_not_depend_on_the_order_of_the_points(family):
    # the kernels start each ray's iterations from its neighbour's solution; the answer must not move
    cfg = _config(family, 4)
    scene, _ = make_scene(family, cfg.geometry, np.random.default_rng(5), (H, W))
    grid = pixel_grid(H, W)
    perm = np.random.default_rng(0).permutation(grid.shape[1])
    fm, fp = forward(scene, grid), forward(scene, grid[:, perm])
    np.testing.assert_array_equal(fm.reason[perm], fp.reason)
    assert np.abs(fm.uv[:, perm] - fp.uv)[:, fp.valid].max() < 1e-6
    (xy, lit), (xp, lp) = backward(scene, grid), backward(scene, grid[:, perm])
    np.testing.assert_array_equal(lit[perm], lp)
    assert np.abs(xy[:, perm] - xp)[:, lp].max() < 1e-6


def test_pixel_grid_is_shared_and_read_only():
    grid = pixel_grid(H, W)
    assert grid is pixel_grid(H, W) and not grid.flags.writeable
    assert grid.shape == (2, H * W) and grid[:, W + 2].tolist() == [2.0, 1.0]


def test_ray_arrays_with_wrong_shapes_are_rejected():
    surface = Surface("plane", np.eye(3), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="directions"):
        intersect(surface, np.zeros((3, 2)), np.zeros((3, 5)))
    with pytest.raises(ValueError, match="points must be"):
        forward(_simple_scene("plane", {}), np.zeros((3, 4)))


@pytest.mark.parametrize("kind", ["cylinder_convex", "sphere_convex"])
@pytest.mark.parametrize("baseline_deg", [20.0, 50.0])
def test_convex_visibility_without_a_cast_matches_the_ray_cast(kind, baseline_deg):
    from projsynth.lens import pixels_to_rays

    scene = _simple_scene(kind, {"radius": 0.3}, baseline_deg=baseline_deg)
    grid = pixel_grid(H, W)
    fm = forward(scene, grid)  # occlusion decided by the outward-normal test
    dirs, _ = pixels_to_rays(scene.projector, grid[0], grid[1])
    t, hit = intersect(scene.surface, np.zeros((3, 1)), dirs)
    X = dirs[:, hit] * t[hit]
    ray = X - scene.C[:, None]
    dist = np.linalg.norm(ray, axis=0)
    tc, _ = intersect(scene.surface, scene.C[:, None], ray / dist)
    seen = np.isfinite(tc) & (tc > dist * (1 - 1e-7))  # the camera's first hit is the point itself
    occluded = (fm.reason[hit] & OCCLUDED) > 0
    considered = (fm.reason[hit] | OCCLUDED) == OCCLUDED  # hit, in frame, lens fine: visibility decides
    assert considered.sum() > 1000 and (~seen[considered]).sum() > 20
    np.testing.assert_array_equal(occluded[considered], ~seen[considered])
