"""Moving-rig sequences: every frame's flow is the exact ray cast of the moved rig, the projector (not
the camera) moves, and each preset stays inside its documented bounds."""

import numpy as np
import pytest

from projsynth.dataset.plan import make_sample, resolve_plan, sample_scene
from projsynth.sim.lens import Lens
from projsynth.sim.motion import (
    BOUNDS,
    CM,
    FRAME_RATE_HZ,
    MOTIONS,
    ORBIT_RATE_DEG_S,
    Trajectory,
    draw_trajectory,
    moved_scene,
    rotation_vector,
)
from projsynth.sim.render import ground_truth
from projsynth.sim.scene import Scene, backward, forward, look_at, pixel_grid, rotation_about
from projsynth.sim.surface import Surface

SIZE = (48, 64)


def _plan(motion, frames=3, transforms="65", seed=5):
    return resolve_plan(
        size=SIZE, seed=seed, split="val", pairs=1, transforms=transforms, blend="paper", frames=frames, motion=motion
    )


@pytest.mark.parametrize("motion", MOTIONS)
def test_each_frame_holds_the_exact_flow_of_its_moved_rig(motion):
    plan = _plan(motion)
    static = make_sample(_plan(None, frames=1), 0)
    base = sample_scene(_plan(None, frames=1), 0).scene
    grid = pixel_grid(*SIZE)
    for k in range(plan.frames):
        s = make_sample(plan, k)
        m = s.params["motion"]
        assert (s.id, s.params["frame"], s.params["sequence"]) == (
            f"val-p00000-r0-t065-f{k:03d}",
            k,
            "val-p00000-r0-t065",
        )
        assert m["time_s"] == pytest.approx(k / FRAME_RATE_HZ)
        # the scene rebuilt from the recorded trajectory gives the stored flow bit for bit
        scene = moved_scene(base, *Trajectory(motion, m["trajectory"]).pose(m["time_s"]))
        flow, valid, _ = ground_truth(scene)
        np.testing.assert_array_equal(valid, s.valid)
        np.testing.assert_array_equal(flow, s.flow)
        assert np.degrees(rotation_vector(Trajectory(motion, m["trajectory"]).pose(m["time_s"])[0])) == pytest.approx(
            m["rotation_deg"], abs=1e-9
        )
        # and it is exact: projected -> captured -> projected closes
        fm = forward(scene, grid)
        back, lit = backward(scene, fm.uv[:, fm.valid])
        assert fm.valid.mean() > 0.3 and lit.mean() > 0.99
        assert np.hypot(*(back[:, lit] - grid[:, fm.valid][:, lit])).max() < 0.01
        assert m["subframes"] == (5 if motion == "vibration" else 1)
    # frame 0 is the rig at rest: the single-frame sample's geometry
    first = make_sample(plan, 0)
    np.testing.assert_array_equal(first.flow, static.flow)
    assert first.params["motion"]["translation_cm"] == [0.0, 0.0, 0.0]
    assert not np.array_equal(make_sample(plan, 2).flow, first.flow)  # and then it moves


def test_the_projector_moves_not_the_camera():
    """Turning the projector about its centre by R: the ray of projector pixel p leaves as the ray of
    pixel p' = K R^T K^-1 p did before, and the camera, which stayed, sees that point where it did."""
    h, w = SIZE
    f = w / (2 * np.tan(np.radians(25)))
    lens = Lens(f, f, (w - 1) / 2, (h - 1) / 2, (0.0,) * 5, w, h)
    target = np.array([0.0, 0.0, 1.0])
    C = target + rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(15)) @ -target
    scene = Scene(lens, lens, look_at(C, target, (0.0, 0.0), 0.0, lens), C, Surface("plane", np.eye(3), target, {}))
    R = rotation_about(np.array([0.3, 1.0, 0.2]), np.radians(1.5))
    moved = moved_scene(scene, R, np.zeros(3))
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    pts = np.array([[10.0, 30.0, 50.0], [8.0, 24.0, 40.0]])
    rays = K @ R @ np.linalg.inv(K) @ np.vstack([pts, np.ones(3)])  # the same world ray, base pixels
    before = forward(scene, rays[:2] / rays[2])
    after = forward(moved, pts)
    assert after.valid.all() and before.valid.all()
    np.testing.assert_allclose(after.uv, before.uv, atol=1e-6)
    # a pure translation of the projector moves the lit point by the translation on a fronto-parallel plane
    shifted = moved_scene(scene, np.eye(3), np.array([2 * CM, 0.0, 0.0]))  # 2 cm to the right
    assert np.allclose(np.asarray(shifted.surface.origin) - scene.surface.origin, [-2 * CM, 0, 0])
    assert np.allclose(shifted.C - scene.C, [-2 * CM, 0, 0])


@pytest.mark.parametrize("motion", MOTIONS)
def test_presets_stay_inside_their_documented_bounds(motion):
    times = np.arange(30) / FRAME_RATE_HZ  # one second
    largest = np.zeros(2)
    for seed in range(40):
        path = draw_trajectory(motion, len(times), np.random.default_rng(seed))
        for t in times:
            rot, centre = path.pose(float(t))
            cm, deg = centre / CM, np.degrees(rotation_vector(rot))
            if motion == "orbit":
                angle = np.degrees(np.linalg.norm(rotation_vector(rot)))
                assert angle <= ORBIT_RATE_DEG_S[1] * t + 1e-9
                assert np.linalg.norm(cm) == pytest.approx(2 * np.sin(np.radians(angle) / 2) * 300, abs=1e-6)
                largest = np.maximum(largest, [np.linalg.norm(cm), angle / max(t, 1e-9)])
                continue
            cm_max, deg_max = BOUNDS[motion]
            if motion == "gust":  # norms: a displacement in one direction, a turn about one axis
                assert np.linalg.norm(cm) <= cm_max + 1e-9 and np.linalg.norm(deg) <= deg_max + 1e-9
                largest = np.maximum(largest, [np.linalg.norm(cm), np.linalg.norm(deg)])
            else:  # per axis
                assert np.abs(cm).max() <= cm_max + 1e-9 and np.abs(deg).max() <= deg_max + 1e-9
                largest = np.maximum(largest, [np.abs(cm).max(), np.abs(deg).max()])
        if motion in ("hover", "gust"):
            assert path.pose(0.0)[1] == pytest.approx(np.zeros(3))
    # and the bounds are not loose by an order of magnitude: the presets do move
    expect = {"hover": (1.5, 0.3), "gust": (3.0, 1.0), "vibration": (0.0, 0.15), "orbit": (5.0, ORBIT_RATE_DEG_S[0])}
    assert largest[0] >= expect[motion][0] and largest[1] >= expect[motion][1], (motion, largest)


def test_vibration_blurs_the_photo_but_not_the_truth():
    plan = _plan("vibration", frames=2)
    s = sample_scene(plan, 1)
    assert len(s.exposure) == 5 and s.motion["exposure_s"] == pytest.approx(1 / 120)
    mid = s.exposure[2]
    np.testing.assert_array_equal(mid.R, s.scene.R)  # the middle sub-exposure is the frame's pose
    ends = [ground_truth(e)[0] for e in (s.exposure[0], s.exposure[-1])]
    assert np.abs(ends[0] - ends[1]).max() > 0.05  # the rig moves within the exposure


def test_rerendering_a_blurred_frame_gives_the_stored_photo_back(tmp_path):
    from projsynth.dataset.generate import generate
    from projsynth.dataset.rerender import Rerenderer
    from projsynth.dataset.shards import ShardReader

    generate(_plan("vibration", frames=2), tmp_path / "ds", shard_size=2)
    reader = ShardReader(tmp_path / "ds")
    try:
        for k in range(2):
            s = reader.read(k)
            view = Rerenderer(tmp_path / "ds").views(k, [s["projected"]])[0]
            np.testing.assert_array_equal(view.image, s["captured"])
    finally:
        reader.close()
