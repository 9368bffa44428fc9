"""Captured images of another size than the projected one: frames, bench, predict and training data."""

import cv2
import numpy as np
import pytest

from projreg.evaluation.bench import run_bench
from projreg.geometry.frames import flow_to_captured, register_any_size, truth_to_projected_frame
from projreg.inference.predict import predict
from projreg.training.data import ShardDataset
from projsynth.dataset.shards import ShardReader
from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import read_flow_exr
from projsynth.sim.render import ground_truth
from projsynth.structured.capture import make_rig, shoot
from projsynth.structured.captured import captured_samples, write_captured_dataset
from projsynth.structured.decode import decode
from projsynth.structured.patterns import make_set, write_patterns

SIZE, CAMERA = (96, 128), (120, 160)


def test_flow_to_captured_inverts_truth_to_projected_frame():
    rng = np.random.default_rng(0)
    flow = rng.uniform(-5, 30, (40, 50, 2)).astype(np.float32)
    valid = np.ones((40, 50), bool)
    scale = (50 / 62.5, 40 / 50.0)
    there, kept = truth_to_projected_frame(flow, valid, scale)
    back = flow_to_captured(there, scale)
    np.testing.assert_allclose(back[kept], flow[kept], atol=1e-4)
    assert kept.mean() > 0.5


def test_register_any_size_measures_a_known_warp_in_captured_pixels():
    """A captured image that is the projected one scaled 1.25x (pixel centres at integers), no shift:
    a method that answers zero flow in the resized frame must come back as the scale's flow."""
    projected = np.random.default_rng(1).integers(0, 255, (64, 80, 3), dtype=np.uint8)
    captured = cv2.resize(projected, (100, 80), interpolation=cv2.INTER_LINEAR)
    flow = register_any_size(lambda a, b: np.zeros(a.shape[:2] + (2,), np.float32), projected, captured)
    ys, xs = np.mgrid[0:64, 0:80]
    np.testing.assert_allclose(flow[..., 0], 1.25 * (xs + 0.5) - 0.5 - xs, atol=1e-5)
    np.testing.assert_allclose(flow[..., 1], 1.25 * (ys + 0.5) - 0.5 - ys, atol=1e-5)


@pytest.fixture(scope="module")
def captured_rig(tmp_path_factory):
    """A virtual rig (camera 1.25x the projector), its graycode decode and a captured dataset of one pair."""
    root = tmp_path_factory.mktemp("captured")
    patterns = make_set("graycode", SIZE)
    write_patterns(patterns, root / "pat")
    rig = make_rig(builtin_table(), 45, 5, SIZE, CAMERA)
    photos = [shoot(rig, img, 5, i) for i, img in enumerate(patterns.images())]
    for name, photo in zip(patterns.names, photos, strict=True):
        cv2.imwrite(str(root / f"{name}.png"), cv2.cvtColor(photo, cv2.COLOR_RGB2BGR))
    result = decode(patterns, np.stack(photos).mean(axis=3, dtype=np.float32) / 255)
    picture = cv2.resize(
        np.random.default_rng(2).integers(0, 255, (12, 16, 3), dtype=np.uint8),
        SIZE[::-1],
        interpolation=cv2.INTER_CUBIC,
    )
    cv2.imwrite(str(root / "picture.png"), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(root / "photo.png"), cv2.cvtColor(shoot(rig, picture, 5, 99), cv2.COLOR_RGB2BGR))
    pairs = [(root / "picture.png", root / "photo.png")]
    samples = captured_samples(pairs, result.flow, result.valid, CAMERA)
    files = [root / f"{n}.png" for n in patterns.names]
    write_captured_dataset(root / "ds", patterns, root / "pat", files, samples, CAMERA)
    return root, ground_truth(rig.scene)


def test_bench_on_decoded_truth_agrees_with_predict_on_exact_truth(captured_rig, tmp_path):
    root, (truth, truth_valid, _) = captured_rig
    report = run_bench(root / "ds", baselines=("dis-medium",), refine="on")
    rows = {r["name"]: r for r in report["results"]}
    assert report["dataset"]["camera_size"] == list(CAMERA)
    predict(root / "picture.png", root / "photo.png", tmp_path / "flow.exr")
    flow, _, _ = read_flow_exr(tmp_path / "flow.exr")
    exact = float(np.hypot(*(flow - truth)[truth_valid].T).mean())
    assert abs(rows["reference"]["epe"] - exact) <= 0.1 * exact, (rows["reference"]["epe"], exact)
    assert np.isfinite(rows["dis-medium"]["epe"])


def test_training_data_sees_captured_pairs_at_the_projected_size(captured_rig):
    root, _ = captured_rig
    item = ShardDataset([root / "ds"], batched=False)[0]
    assert item["img0"].shape == item["img1"].shape == (3, *SIZE)
    flow, valid = item["flow"].permute(1, 2, 0).numpy(), item["valid"].numpy()
    back = flow_to_captured(flow, (SIZE[1] / CAMERA[1], SIZE[0] / CAMERA[0]))
    s = ShardReader(root / "ds").read(0)
    np.testing.assert_allclose(back[valid], s["flow"][valid], atol=1e-3)
    assert valid.sum() >= 0.95 * s["valid"].sum()
