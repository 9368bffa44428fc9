import cv2
import numpy as np
import pytest

from projreg import ProjregError
from projreg.evaluation.baselines import BASELINES, SiftRansac, make_baseline, parse_baselines
from projreg.evaluation.metrics import epe_map
from projreg.geometry.homography import homography_flow
from projreg.geometry.images import to_gray

H, W = 128, 160
SHIFT = (5.0, 3.0)  # captured(x) = projected(x - SHIFT): the forward flow is +SHIFT
M = 16  # interior margin: borders have no matching content


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Smoothed random noise at three scales: textured everywhere, not periodic."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.float32)
    for cell in (32, 12, 4):
        small = rng.random((h // cell + 2, w // cell + 2, 3)).astype(np.float32)
        big = cv2.resize(small, (w + 2 * cell, h + 2 * cell), interpolation=cv2.INTER_CUBIC)
        img += big[cell : cell + h, cell : cell + w]
    img = (img - img.min()) / (img.max() - img.min())
    return (img * 255).round().astype(np.uint8)


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    projected = texture(H, W)
    shift = np.float32([[1, 0, SHIFT[0]], [0, 1, SHIFT[1]]])
    captured = cv2.warpAffine(projected, shift, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return projected, captured


@pytest.mark.parametrize("name", ["dis-ultrafast", "dis-fast", "dis-medium", "farneback"])
def test_dense_baselines_recover_translation(pair, name):
    projected, captured = pair
    flow = make_baseline(name).predict(projected, captured)
    assert flow.shape == (H, W, 2) and flow.dtype == np.float32
    interior = flow[M:-M, M:-M].reshape(-1, 2)
    med = np.median(interior, axis=0)
    assert med[0] > 0 and med[1] > 0, "flow must point projected -> captured"
    np.testing.assert_allclose(med, SHIFT, atol=0.3)


@pytest.mark.parametrize("name", ["dis-medium", "farneback"])
def test_flow_direction_by_resampling(pair, name):
    # Forward: projected(p) == captured(p + F(p)), so sampling captured at p + F rebuilds projected.
    projected, captured = pair
    flow = make_baseline(name).predict(projected, captured)
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    rebuilt = cv2.remap(captured, x + flow[..., 0], y + flow[..., 1], cv2.INTER_LINEAR)
    err = np.abs(rebuilt.astype(np.float32) - projected)[M:-M, M:-M].mean()
    wrong = cv2.remap(captured, x - flow[..., 0], y - flow[..., 1], cv2.INTER_LINEAR)
    assert err < 3.0 < np.abs(wrong.astype(np.float32) - projected)[M:-M, M:-M].mean()


def test_equalize_handles_contrast_change(pair):
    projected, captured = pair
    # A monotone contrast/brightness change, which equalisation largely undoes.
    dim = (captured.astype(np.float32) * 0.4 + 90).astype(np.uint8)
    err = {}
    for eq in (False, True):
        flow = make_baseline("dis-ultrafast", equalize=eq).predict(projected, dim)
        err[eq] = np.hypot(*(flow[M:-M, M:-M] - SHIFT).transpose(2, 0, 1)).mean()
    assert err[True] < 0.3 and err[True] < err[False] / 2


def test_to_gray_matches_opencv():
    img = texture(8, 8)
    np.testing.assert_array_equal(to_gray(img), cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
    assert to_gray(img, equalize=True).max() == 255


def test_homography_flow_hand_values():
    Hm = np.array([[2, 0, 1], [0, 1, -3], [0, 0, 1]], np.float64)  # x' = 2x + 1, y' = y - 3
    flow = homography_flow(Hm, 2, 3)
    np.testing.assert_allclose(flow[..., 0], [[1, 2, 3], [1, 2, 3]])
    np.testing.assert_allclose(flow[..., 1], -3)
    Hp = np.array([[1, 0, 0], [0, 1, 0], [0.5, 0, 1]], np.float64)  # x' = x / (1 + x / 2)
    np.testing.assert_allclose(homography_flow(Hp, 1, 3)[0, :, 0], [0, 1 / 1.5 - 1, 2 / 2 - 2], atol=1e-6)


def test_sift_ransac_recovers_homography():
    projected = texture(H, W, seed=1)
    cam_from_proj = np.array([[1.03, 0.04, 4.0], [-0.03, 0.97, 6.0], [1.5e-4, -1e-4, 1.0]])
    captured = cv2.warpPerspective(projected, cam_from_proj, (W, H), flags=cv2.INTER_LINEAR)
    baseline = make_baseline("sift-ransac")
    flow = baseline.predict(projected, captured)
    assert baseline.last_status == "ok" and baseline.last_inliers >= 20
    gt = homography_flow(cam_from_proj, H, W)
    y, x = np.mgrid[0:H, 0:W]
    inside = (x + gt[..., 0] > 1) & (x + gt[..., 0] < W - 2) & (y + gt[..., 1] > 1) & (y + gt[..., 1] < H - 2)
    assert np.median(epe_map(flow, gt)[inside]) < 0.5
    np.testing.assert_array_equal(flow, baseline.predict(projected, captured))  # deterministic


def test_sift_ransac_blank_images_give_zero_flow():
    blank = np.full((H, W, 3), 128, np.uint8)
    baseline = SiftRansac()
    flow = baseline.predict(blank, blank)
    assert flow.shape == (H, W, 2) and not flow.any()
    assert baseline.last_status == "too-few-matches" and baseline.last_inliers == 0


def test_registry_and_names():
    assert set(BASELINES) == {"dis-ultrafast", "dis-fast", "dis-medium", "farneback", "sift-ransac", "refine-only"}
    for name in BASELINES:
        assert make_baseline(name).name == name
    assert parse_baselines("dis-fast,farneback") == ["dis-fast", "farneback"]
    assert parse_baselines(" sift-ransac , dis-fast,sift-ransac,") == ["sift-ransac", "dis-fast"]


def test_bad_arguments_raise():
    with pytest.raises(ProjregError, match=r"unknown baseline 'raft'; choose from dis-ultrafast, .*sift"):
        make_baseline("raft")
    with pytest.raises(ProjregError, match="unknown baseline 'dis-slow'"):
        parse_baselines("dis-fast,dis-slow")
    with pytest.raises(ProjregError, match="no baseline named"):
        parse_baselines(" , ")
    img = texture(16, 16)
    with pytest.raises(ProjregError, match="captured must be a uint8 RGB array"):
        make_baseline("dis-fast").predict(img, img.astype(np.float32))
    with pytest.raises(ProjregError, match="differ"):
        make_baseline("dis-fast").predict(img, texture(16, 24))


def bent_homography_pair(h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(projected, captured, forward flow): a homography composed with a smooth sine bend, written
    here (not by projsynth); the captured image samples the projected one at the inverted map."""
    projected = texture(h, w, seed=3)
    hom = np.array([[1.04, 0.03, 9.0], [-0.02, 0.98, -6.0], [2e-5, 1e-5, 1.0]])
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    truth = homography_flow(hom, h, w)
    truth[..., 1] += 2.5 * np.sin(2 * np.pi * x / w)
    inv = -truth  # captured(p + F(p)) = projected(p): fixed-point iteration for the inverse map
    for _ in range(30):
        px, py = x + inv[..., 0], y + inv[..., 1]
        inv = -cv2.remap(truth, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mx, my = x + inv[..., 0], y + inv[..., 1]
    captured = cv2.remap(projected, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return projected, captured, truth


def test_refine_only_recovers_a_bent_homography_written_here():
    projected, captured, truth = bent_homography_pair(192, 256)
    pred = make_baseline("refine-only").predict(projected, captured)
    err = epe_map(pred.flow, truth)[M:-M, M:-M]
    sift = epe_map(make_baseline("sift-ransac").predict(projected, captured), truth)[M:-M, M:-M]
    assert pred.registered and np.median(err) < 0.3, np.median(err)
    assert np.median(err) < 0.5 * np.median(sift), (np.median(err), np.median(sift))
    assert pred.claimed is not None and pred.claimed.mean() > 0.7


def test_refine_only_reports_a_blank_pair_as_not_registered():
    blank = np.full((H, W, 3), 128, np.uint8)
    pred = make_baseline("refine-only").predict(blank, blank)
    assert not pred.registered and "textureless" in pred.reason and not pred.claimed.any()
