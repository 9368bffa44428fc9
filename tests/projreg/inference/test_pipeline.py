"""The pipeline object: a quality resolves once into the network's side, the finer pass and the refiner;
its tracking loop is the tracker run frame by frame, in the camera's pixels, and refuses a frame of
another size naming it."""

import cv2
import numpy as np
import pytest

from projreg import ProjregError
from projreg.geometry.frames import register_any_size
from projreg.inference.pipeline import Pipeline
from projreg.refine.config import QUALITIES
from projsynth.dataset.shards import ShardReader


@pytest.fixture(scope="module")
def frames(tiny_sequences):
    reader = ShardReader(tiny_sequences)
    try:
        return [(s["projected"], s["captured"]) for s in (reader.read(k) for k in range(3))]  # one sequence
    finally:
        reader.close()


def test_a_quality_resolves_into_the_network_side_the_finer_pass_and_the_refiner(tiny_ckpt):
    balanced = Pipeline(tiny_ckpt, device="cpu")
    assert (balanced.quality, balanced.network_side, balanced.finer_side) == ("balanced", 256, 512)
    assert balanced.refiner.config == QUALITIES["balanced"].refine
    capped = Pipeline(tiny_ckpt, device="cpu", max_side=200)  # a user's --max-side caps both passes
    assert (capped.network_side, capped.finer_side) == (200, None)
    fast = Pipeline(tiny_ckpt, quality="fast", device="cpu", refine=False)
    assert (fast.network_side, fast.finer_side, fast.refiner) == (256, None, None)
    with pytest.raises(ProjregError, match="tracking and refining need it"):
        fast.tracker()
    with pytest.raises(ProjregError, match="--quality 'best'"):
        Pipeline(tiny_ckpt, quality="best", device="cpu")


def test_track_is_the_tracker_frame_by_frame_in_the_cameras_pixels(tiny_ckpt, frames):
    pipeline = Pipeline(tiny_ckpt, quality="fast", device="cpu")
    bigger = [(a, cv2.resize(b, (144, 96), interpolation=cv2.INTER_LINEAR)) for a, b in frames]
    tracker = pipeline.tracker()
    for (a, b), reg in zip(bigger, pipeline.track(bigger), strict=True):
        expected = register_any_size(tracker, a, b)
        assert reg.step == tracker.last and reg.camera_size == (96, 144)
        np.testing.assert_array_equal(reg.flow, expected.flow)
        np.testing.assert_array_equal(reg.claimed, expected.claimed)
    assert [r.step for r in pipeline.track(frames)][0] == "full"


def test_a_frame_of_another_size_is_refused_naming_it(tiny_ckpt, frames):
    pipeline = Pipeline(tiny_ckpt, quality="fast", device="cpu")
    shrunk = frames[:2] + [(frames[2][0], frames[2][1][:, :80])]
    run = pipeline.track(shrunk, where="--captured")
    next(run), next(run)
    with pytest.raises(ProjregError, match=r"--captured\[2\]: frame sizes changed"):
        next(run)
