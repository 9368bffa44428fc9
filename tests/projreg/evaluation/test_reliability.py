import doctest

import numpy as np

from projreg.evaluation import reliability
from projreg.evaluation.reliability import BANDS, ReliabilityAccumulator


def test_the_module_example_runs():
    assert doctest.testmod(reliability).failed == 0


def test_bands_count_the_pixels_within_1_and_3_px_by_hand():
    gt = np.zeros((2, 4, 2), np.float32)
    flow = np.zeros_like(gt)
    flow[..., 0] = [[0.5, 2.0, 4.0, 0.0], [1.0, 3.0, 0.2, 9.0]]  # errors of each pixel
    confidence = np.array([[0.95, 0.95, 0.95, 1.0], [0.5, 0.5, 0.05, 0.05]], np.float32)
    valid = np.ones((2, 4), bool)
    valid[0, 3] = False  # not counted
    acc = ReliabilityAccumulator()
    acc.add(flow, gt, valid, confidence)
    acc.add(flow, gt, np.zeros_like(valid), confidence)  # no valid pixel: nothing
    bands = {b["band"]: b for b in acc.result()}
    assert list(bands) == [f"{lo:g}-{hi:g}" for lo, hi in zip(BANDS, BANDS[1:], strict=False)]
    top, mid, low = bands["0.9-1"], bands["0.5-0.7"], bands["0-0.1"]
    assert (top["pixels"], top["within1"], top["within3"]) == (3, 1 / 3, 2 / 3)
    assert (mid["pixels"], mid["within1"], mid["within3"]) == (2, 0.5, 1.0)
    assert (low["pixels"], low["within1"], low["within3"], low["share"]) == (2, 0.5, 0.5, 2 / 7)
    assert bands["0.3-0.5"]["pixels"] == 0 and bands["0.3-0.5"]["within1"] is None
