"""Re-rendering a sample with other projector images: the same scene, and the noise shared or drawn anew."""

import numpy as np

from projsynth.dataset.rerender import Rerenderer
from projsynth.dataset.shards import ShardReader


def test_views_share_the_stored_photo_s_noise_or_draw_their_own(mixed_ds):
    reader, rerenderer = ShardReader(mixed_ds), Rerenderer(mixed_ds)
    s = reader.read(3)
    grey = np.full_like(s["projected"], 128)
    same = rerenderer.views(3, [s["projected"], grey, grey])
    np.testing.assert_array_equal(same[0].image, s["captured"])  # the stored photo, byte for byte
    np.testing.assert_array_equal(same[1].image, same[2].image)  # one draw for every image
    fresh = rerenderer.views(3, [s["projected"], grey, grey], same_noise=False)
    np.testing.assert_array_equal(fresh[0].image, s["captured"])  # the stream starts where the stored photo's did
    noise = fresh[1].image.astype(int) - fresh[2].image
    assert (noise != 0).mean() > 0.3 and abs(noise.mean()) < 0.5  # a draw of its own, the same scene
