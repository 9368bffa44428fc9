import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from projreg import ProjregError
from projreg.evaluation.metrics import KEYS, EPEAccumulator, bucket_masks, epe_map, summarize

# 2 x 3 ground truth with magnitudes [[0, 10, 40], [5, 50, 10]]: both bucket boundaries are exact.
GT = np.array([[[0, 0], [6, 8], [24, 32]], [[3, 4], [30, 40], [10, 0]]], np.float32)
EPE = np.array([[0.5, 2.0, 4.0], [6.0, 1.0, 3.0]], np.float32)
VALID = np.array([[True, True, True], [True, True, False]])


def _pred(gt: np.ndarray, epe: np.ndarray) -> np.ndarray:
    return gt + np.stack([epe, np.zeros_like(epe)], axis=-1)  # error along x only


def test_epe_map_hand_values():
    pred = np.zeros((1, 2, 2), np.float32)
    gt = np.array([[[3, 4], [-1, 0]]], np.float32)
    np.testing.assert_allclose(epe_map(pred, gt), [[5.0, 1.0]])


def test_bucket_boundaries():
    gt = np.array([[[9.999, 0], [10, 0], [40, 0], [40.001, 0], [0, -41]]], np.float32)
    m = bucket_masks(gt)
    assert m["s0-10"].tolist() == [[True, False, False, False, False]]
    assert m["s10-40"].tolist() == [[False, True, True, False, False]]
    assert m["s40+"].tolist() == [[False, False, False, True, True]]


def test_summarize_hand_computed():
    r = summarize(_pred(GT, EPE), GT, VALID)
    assert list(r) == list(KEYS)
    # valid EPEs 0.5, 2, 4, 6, 1; the pixel with EPE 3 is invalid
    assert r["epe"] == pytest.approx(13.5 / 5)
    assert r["s0-10"] == pytest.approx((0.5 + 6.0) / 2)  # |gt| = 0, 5
    assert r["s10-40"] == pytest.approx((2.0 + 4.0) / 2)  # |gt| = 10, 40 (the other 10 is invalid)
    assert r["s40+"] == pytest.approx(1.0)  # |gt| = 50
    assert (r["px1"], r["px3"], r["px5"]) == pytest.approx((3 / 5, 2 / 5, 1 / 5))  # EPE 1.0 is not > 1
    assert r["image_epe"] == pytest.approx(2.7)
    assert (r["pixels"], r["images"]) == (5, 1)


def test_invalid_pixels_ignored():
    pred = _pred(GT, EPE)
    pred[1, 2] = 1e6  # invalid: must not change anything
    assert summarize(pred, GT, VALID) == summarize(_pred(GT, EPE), GT, VALID)


def test_empty_bucket_is_none_and_json_null():
    gt = np.zeros((2, 2, 2), np.float32)
    r = summarize(gt + 1, gt, np.ones((2, 2), bool))
    assert r["s0-10"] == pytest.approx(np.sqrt(2))
    assert r["s10-40"] is None and r["s40+"] is None
    assert json.loads(json.dumps(r))["s40+"] is None


def test_empty_accumulator_and_all_invalid_image():
    assert EPEAccumulator().result() == {k: None for k in KEYS} | {"pixels": 0, "images": 0}
    acc = EPEAccumulator()
    acc.add(GT, GT, np.zeros((2, 3), bool))
    r = acc.result()
    assert r["epe"] is None and r["image_epe"] is None and r["images"] == 1 and r["pixels"] == 0


def test_pooled_differs_from_per_image_mean():
    gt = np.zeros((1, 4, 2), np.float32)
    acc = EPEAccumulator()
    acc.add(_pred(gt, np.ones((1, 4), np.float32)), gt, np.array([[True, False, False, False]]))
    acc.add(_pred(gt, np.full((1, 4), 3, np.float32)), gt, np.ones((1, 4), bool))
    r = acc.result()
    assert r["epe"] == pytest.approx((1 + 3 * 4) / 5)
    assert r["image_epe"] == pytest.approx((1 + 3) / 2)


def test_merge_equals_single_accumulator():
    rng = np.random.default_rng(0)
    samples = [
        (rng.normal(0, 30, (5, 7, 2)), rng.normal(0, 30, (5, 7, 2)), rng.random((5, 7)) > 0.3)
        for _ in range(6)
    ]
    whole, a, b = EPEAccumulator(), EPEAccumulator(), EPEAccumulator()
    for i, s in enumerate(samples):
        whole.add(*s)
        (a if i % 2 else b).add(*s)
    merged = a.merge(b).result()
    expected = whole.result()
    assert merged["pixels"] == expected["pixels"] and merged["images"] == expected["images"] == 6
    for k in KEYS:
        assert merged[k] == pytest.approx(expected[k]), k


def test_bad_arguments_raise():
    with pytest.raises(ProjregError, match="pred shape"):
        epe_map(np.zeros((2, 3, 2)), np.zeros((3, 2, 2)))
    with pytest.raises(ProjregError, match="gt must be a flow array"):
        epe_map(np.zeros((2, 3, 2)), np.zeros((2, 3)))
    with pytest.raises(ProjregError, match="valid must be a bool array"):
        summarize(GT, GT, np.ones((2, 3), np.uint8))


_flow_sets = st.lists(
    st.tuples(
        st.integers(1, 4).flatmap(
            lambda w: arrays(np.float32, (2, w, 2), elements=st.floats(-60, 60, width=32))
        ),
        st.integers(0, 2**32 - 1),
    ),
    min_size=1,
    max_size=4,
)


@settings(max_examples=50, deadline=None)
@given(st.lists(_flow_sets, min_size=1, max_size=3))
def test_pooled_epe_of_union_is_count_weighted_mean(sets):
    whole, parts = EPEAccumulator(), []
    for images in sets:
        acc = EPEAccumulator()
        for gt, seed in images:
            rng = np.random.default_rng(seed)
            pred = gt + rng.normal(0, 5, gt.shape).astype(np.float32)
            valid = rng.random(gt.shape[:2]) > 0.5
            acc.add(pred, gt, valid)
            whole.add(pred, gt, valid)
        parts.append(acc.result())
    r = whole.result()
    assert r["pixels"] == sum(p["pixels"] for p in parts)
    weighted = [(p["epe"] * p["pixels"], p["pixels"]) for p in parts if p["pixels"]]
    if not weighted:
        assert r["epe"] is None
    else:
        assert r["epe"] == pytest.approx(sum(s for s, _ in weighted) / sum(n for _, n in weighted))


def test_worst_pairs_and_claimed_pixels_hand_computed():
    gt = np.zeros((1, 4, 2), np.float32)
    acc = EPEAccumulator()
    for k, e in enumerate([1.0, 5.0, 2.0, 4.0, 3.0]):
        claimed = np.array([[True, True, False, False]]) if k == 1 else None
        err = np.array([[e, e, 9.0, 9.0]], np.float32) if k == 1 else np.full((1, 4), e, np.float32)
        acc.add(_pred(gt, err), gt, np.ones((1, 4), bool), claimed, f"s{k}")
    r = acc.result()
    per_pair = [1.0, (5 + 5 + 9 + 9) / 4, 2.0, 4.0, 3.0]  # 1, 7, 2, 4, 3
    assert r["pair_median"] == pytest.approx(3.0)
    assert r["pair_p90"] == pytest.approx(4 + 0.6 * (7 - 4))  # linear interpolation between 4 and 7
    assert (r["worst_epe"], r["worst_id"]) == (pytest.approx(max(per_pair)), "s1")
    assert r["claimed"] == pytest.approx(18 / 20) and r["claimed_mean"] == pytest.approx((4 * 1 + 0.5) / 5)
    assert r["epe_claimed"] == pytest.approx((4 * (1 + 2 + 4 + 3) + 2 * 5) / 18)
    with pytest.raises(ProjregError, match="claimed must be a bool"):
        acc.add(gt, gt, np.ones((1, 4), bool), np.ones((1, 3), bool))
