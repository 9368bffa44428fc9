"""Fixtures of the refinement's tests: projsynth samples and a picture to render pairs from."""

import cv2
import numpy as np
import pytest

from projsynth.content.procedural import render_procedural
from projsynth.dataset.shards import ShardReader

from ..conftest import make_shards


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    """lens, convex cylinder, concave sphere, wave, bumps at severity 2 (studio and noisy), 128 x 160."""
    root = make_shards(tmp_path_factory.mktemp("refine") / "d", size=(128, 160), transforms="25,46,105,126,145")
    reader = ShardReader(root)
    try:
        return [reader.read(k) for k in range(len(reader))]
    finally:
        reader.close()


@pytest.fixture(scope="module")
def picture():
    rng = np.random.default_rng(7)
    return cv2.resize(render_procedural("natural", "urban", (192, 256), rng), (256, 192))
