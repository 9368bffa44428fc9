import numpy as np
import pytest

from projsynth.dataset.transforms import FAMILIES, builtin_table
from projsynth.sim.lens import Lens
from projsynth.sim.rig import make_scene
from projsynth.sim.scene import OCCLUDED, Scene, backward, forward, look_at, pixel_grid, rotation_about
from projsynth.sim.surface import Surface, intersect

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
    dirs, _ = __import__("projsynth.sim.lens", fromlist=["pixels_to_rays"]).pixels_to_rays(
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
    from projsynth.sim.lens import pixels_to_rays

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
    from projsynth.sim.lens import pixels_to_rays

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


@pytest.mark.parametrize("k1", [-0.21, -0.28])
def test_lens_validity_does_not_depend_on_the_neighbours_guesses(k1):
    # the maps start each undistortion from the neighbouring pixels' shifts; near the fold radius a
    # guess can start Newton past it, which must not make a pixel invalid (a zero guess decides)
    from projsynth.sim.lens import pixels_to_rays
    from projsynth.sim.scene import LENS

    h, w = 192, 256
    strong = Lens(192.5, 192.5, (w - 1) / 2, (h - 1) / 2, (k1, -0.02, 0.008, -0.008, 0.0), w, h)
    plain = Lens(192.5, 192.5, (w - 1) / 2, (h - 1) / 2, (0.0,) * 5, w, h)
    target = np.array([0.0, 0.0, 1.0])
    C = np.array([0.02, 0.0, 0.0])  # camera beside the projector: every hit point lies in front of it
    scene = Scene(strong, plain, look_at(C, target, (0.0, 0.0), 0.0, plain), C, Surface("plane", np.eye(3), target))
    grid = pixel_grid(h, w)
    _, alone = pixels_to_rays(strong, grid[0], grid[1])  # each pixel from a zero guess
    assert 0 < (~alone).sum() < alone.size // 2  # the fold radius cuts the corners
    fm = forward(scene, grid)
    np.testing.assert_array_equal((fm.reason & LENS) == 0, alone)
    scene_back = Scene(plain, strong, np.eye(3), np.zeros(3), Surface("plane", np.eye(3), target))
    _, lit = backward(scene_back, grid)  # camera = the strong lens, projector at the same place
    assert not lit[~alone].any()  # a camera pixel that cannot be undistorted is never lit
    np.testing.assert_array_equal(lit[alone], backward(scene_back, grid[:, alone])[1])


def _height(surface, x, y):
    """The height field of a wave or bumps surface at local (x, y), in numpy (independent of the kernels)."""
    h = np.zeros_like(x)
    for a, p, q, r in surface.params.get("waves", []):
        h += a * np.sin(p * x + q * y + r)
    for a, cx, cy, s in surface.params.get("bumps", []):
        h += a * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return h


@pytest.mark.parametrize("family", ["wave", "bumps"])
def test_heightfield_casts_find_the_first_root_of_shallow_and_steep_rays(family):
    # against a dense scan of g(t) = z - h(x, y) along each ray: the cast's root must have g < 0
    # everywhere before it (no earlier crossing skipped by a certified Newton step or a marching step)
    cfg = _config(family, 4)
    surface = make_scene(family, cfg.geometry, np.random.default_rng(7), (H, W))[0].surface
    rng = np.random.default_rng(1)
    n, R, origin = 1500, surface.rotation, surface.origin
    # eyes in front of the surface, 2 away from random points of it, from 40 degrees to grazing:
    # some of those points hide behind a crest, so their rays cross the surface earlier
    targets = np.c_[rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n)]
    targets = np.c_[targets, _height(surface, targets[:, 0], targets[:, 1])]
    elev, az = rng.uniform(np.radians(3), np.radians(40), n), rng.uniform(0, 2 * np.pi, n)
    back = np.c_[np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), -np.sin(elev)]  # towards the eye
    eyes_local = targets + 2.0 * back
    bound = sum(abs(term[0]) for term in surface.params.get("waves", surface.params.get("bumps")))
    front = eyes_local[:, 2] < -bound  # casts require the eye in front of the slab |z| <= bound
    assert front.mean() > 0.8
    eyes_local, back = eyes_local[front], back[front]
    t, hit = intersect(surface, (R @ eyes_local.T) + origin[:, None], R @ -back.T)
    assert hit.mean() > 0.99
    assert (t[hit] < 2.0 - 1e-3).sum() > 20  # rays stopped by a crest before their target
    s = np.linspace(0, 1, 4001)[:, None]  # dense scan up to each root
    for j in np.nonzero(hit)[0]:
        pts = eyes_local[j] + (s * t[j]) * (-back[j])
        g = pts[:, 2] - _height(surface, pts[:, 0], pts[:, 1])
        assert abs(g[-1]) < 1e-8, (j, g[-1])  # the root is on the surface
        assert (g[:-2] < 0).all(), (family, j)  # and nothing was crossed before it
