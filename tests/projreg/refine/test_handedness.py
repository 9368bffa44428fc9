"""Handedness: SIFT's descriptors of a mirrored image, and the mirrored-capture check built on them."""

import cv2
import numpy as np
import pytest

from projreg.refine.handedness import MIRRORED, Features, check, handedness


@pytest.fixture(scope="module")
def gray():
    skimage = pytest.importorskip("skimage.data")
    return cv2.resize(cv2.cvtColor(skimage.astronaut(), cv2.COLOR_RGB2GRAY), (256, 192), interpolation=cv2.INTER_AREA)


def test_the_permutation_gives_the_descriptor_sift_computes_in_the_mirrored_image(gray):
    """A keypoint mirrored left-right (its angle reflected) has, in the mirrored image, the descriptor that
    the permutation makes of its own: far closer than to the unpermuted one, or to another keypoint's."""
    sift = cv2.SIFT_create()
    keypoints, descriptors = sift.detectAndCompute(gray, None)
    w = gray.shape[1]
    mirrored = [cv2.KeyPoint(w - 1 - k.pt[0], k.pt[1], k.size, (180 - k.angle) % 360) for k in keypoints]
    kept, computed = sift.compute(np.ascontiguousarray(gray[:, ::-1]), mirrored)
    assert len(kept) == len(keypoints)
    permuted = np.linalg.norm(descriptors[:, MIRRORED] - computed, axis=1)
    plain = np.linalg.norm(descriptors - computed, axis=1)
    other = np.linalg.norm(np.roll(descriptors[:, MIRRORED], 1, axis=0) - computed, axis=1)
    assert np.median(permuted) < 0.4 * np.median(plain)  # 0.31 here: interpolation differs at small scales
    assert np.median(permuted) < 0.4 * np.median(other)


@pytest.mark.parametrize(
    "view, mirrored",
    [
        (lambda g: g[:, ::-1], True),  # left-right
        (lambda g: g[::-1], True),  # up-down
        (lambda g: g[::-1, ::-1], False),  # turned 180 degrees: a camera upside down, not a mirror
        (lambda g: g, False),
    ],
)
def test_a_mirrored_capture_is_told_from_a_turned_one(gray, view, mirrored):
    hand = handedness(Features.of(gray, 256), Features.of(np.ascontiguousarray(view(gray)), 256))
    assert hand.is_mirrored(30, 3.0) == mirrored, hand


def test_pictures_without_features_are_not_mirrored():
    flat = np.full((64, 80), 128, np.uint8)
    hand = handedness(Features.of(flat, 256), Features.of(flat, 256))
    assert (hand.direct, hand.mirrored) == (0, 0)


@pytest.mark.parametrize("turn, mirrored", [(lambda g: g.T, True), (np.rot90, False)])
def test_a_camera_turned_a_quarter_and_stretched_to_the_projectors_aspect(turn, mirrored):
    """A portrait capture resized to the landscape projector's aspect (a 1.78x anisotropic stretch, which
    SIFT does not match across): the coins transposed (a mirror) are found mirrored at the swapped aspect,
    though not at their own; the coins turned a quarter (not a mirror) are not."""
    skimage = pytest.importorskip("skimage.data")
    gray = cv2.resize(skimage.coins(), (256, 192), interpolation=cv2.INTER_AREA)
    capture = cv2.resize(np.ascontiguousarray(turn(gray)), (256, 192), interpolation=cv2.INTER_AREA)
    projected = Features.of(gray, 256)
    hand = check(projected, capture, 256, 30, 3.0)
    assert hand.is_mirrored(30, 3.0) == mirrored, hand
    if mirrored:  # the capture's own aspect alone did not say
        assert not handedness(projected, Features.of(capture, 256)).is_mirrored(30, 3.0)
    else:  # the direct map is found at the swapped aspect
        assert hand.direct >= 30, hand


def test_the_mirrored_homography_is_the_cameras_map():
    """The transposed coins resized to the projector's aspect: the mirrored matches' homography, as a flow
    on the pair's own grid, is the transposition and stretch written here, to a pixel."""
    skimage = pytest.importorskip("skimage.data")
    h, w = 192, 256
    gray = cv2.resize(skimage.coins(), (w, h), interpolation=cv2.INTER_AREA)
    capture = cv2.resize(np.ascontiguousarray(gray.T), (w, h), interpolation=cv2.INTER_AREA)
    hand = check(Features.of(gray, 256), capture, 256, 30, 3.0)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    # projected (x, y) is the transposed image's (column y, row x), resized by w / h and h / w (pixel centres)
    truth = np.stack([(y + 0.5) * w / h - 0.5 - x, (x + 0.5) * h / w - 0.5 - y], axis=-1)
    error = np.linalg.norm(hand.mirror_flow((h, w)) - truth, axis=-1)
    assert np.median(error) < 1.0 and np.percentile(error, 95) < 2.0, (np.median(error), error.max())
