import shutil

import numpy as np
import pytest
from torch.utils.data import DataLoader

from projreg import ProjregError
from projreg.training.data import Augment, ShardDataset, StreamSampler, augment_sample, crop
from projsynth.sim.photometric import sample_bilinear


@pytest.fixture(scope="module")
def sample(tiny_train):
    ds = ShardDataset([tiny_train])
    s = ds.readers[0].read(3)
    return s["projected"], s["captured"], s["flow"], s["valid"]


def _coordinate_error(flow, valid, aug, seed):
    """Augment coordinate-encoding images (R = x, G = y) with the flow; return, per valid augmented
    pixel, |original camera position seen at p + F'(p) - (p_o + F(p_o))| in original pixels."""
    h, w = valid.shape
    ys, xs = np.mgrid[0:h, 0:w]
    coords = np.dstack([xs, ys, np.zeros_like(xs)]).astype(np.uint8)
    a0, a1, f, v = augment_sample(coords, coords, flow, valid, aug, np.random.default_rng(seed))
    py, px = np.nonzero(v)
    p_o = a0[py, px, :2].astype(np.float64)  # original projected pixel of each augmented pixel
    rgba = np.dstack([a1, a1[..., :1]])
    seen = sample_bilinear(rgba, px + f[py, px, 0], py + f[py, px, 1])[:, :2]
    want = p_o + flow[p_o[:, 1].round().astype(int), p_o[:, 0].round().astype(int)]
    return np.hypot(*(seen - want).T), v


def test_flips_and_crops_keep_ground_truth_exact(sample):
    _, _, flow, valid = sample
    aug = Augment(crop=(48, 64), scale=(1.0, 1.0), photometric=False)
    for seed in range(8):
        err, v = _coordinate_error(flow, valid, aug, seed)
        assert v.sum() > 100
        assert err.max() < 1e-3, (seed, err.max())


def test_rescale_keeps_ground_truth_within_interpolation_error(sample):
    _, _, flow, valid = sample
    for s in (0.85, 1.2):
        aug = Augment(crop=(48, 64), scale=(s, s), flip=False, photometric=False)
        err, v = _coordinate_error(flow, valid, aug, 0)
        # positions are compared in original pixels, images were resampled with a uint8 result
        assert v.mean() > 0.2 and np.median(err) < 0.6, (s, np.median(err))


def test_crop_marks_flow_leaving_the_window_invalid(sample):
    img0, img1, flow, valid = sample
    c0, c1, f, v = crop(img0, img1, flow, valid, (40, 40), np.random.default_rng(1))
    gy, gx = np.mgrid[0:40, 0:40]
    u, w = gx + f[..., 0], gy + f[..., 1]
    assert ((u[v] >= 0) & (u[v] <= 39) & (w[v] >= 0) & (w[v] <= 39)).all()
    assert (f[~v] == 0).all()


def test_stream_is_deterministic_resumable_and_sharded():
    a = StreamSampler(10, seed=4)
    first = [x for _, x in zip(range(25), a, strict=False)]
    again = [x for _, x in zip(range(25), StreamSampler(10, seed=4), strict=False)]
    assert first == again
    resumed = [x for _, x in zip(range(15), StreamSampler(10, seed=4, start=10), strict=False)]
    assert resumed == first[10:]
    assert sorted(i for i, _ in first[:10]) == list(range(10))  # an epoch visits every sample once
    r0 = [x for _, x in zip(range(5), StreamSampler(10, seed=4, rank=0, world=2), strict=False)]
    r1 = [x for _, x in zip(range(5), StreamSampler(10, seed=4, rank=1, world=2), strict=False)]
    assert [x for pair in zip(r0, r1, strict=True) for x in pair] == first[:10]


def test_batches_do_not_depend_on_worker_count(tiny_train):
    ds = ShardDataset([tiny_train], Augment(crop=(48, 64)))

    def batches(workers):
        loader = DataLoader(ds, batch_size=3, sampler=StreamSampler(len(ds), seed=1), num_workers=workers)
        it = iter(loader)
        return [next(it) for _ in range(3)]

    for b0, b2 in zip(batches(0), batches(2), strict=True):
        for k in b0:
            assert (b0[k] == b2[k]).all()


def test_missing_or_corrupt_shard_names_it(tiny_train, tmp_path):
    with pytest.raises(ProjregError, match="nowhere"):
        ShardDataset([tmp_path / "nowhere"])
    broken = tmp_path / "broken"
    shutil.copytree(tiny_train, broken)
    (broken / "shard-00001.h5").write_bytes(b"not hdf5")
    ds = ShardDataset([broken])
    with pytest.raises(ProjregError, match="shard-00001.h5"):
        ds[9]
