"""Training data: a torch ``Dataset`` over projsynth shard directories, with flow-consistent augmentation.

Determinism: the sample order and every augmentation draw are a pure function of
``(seed, position in the stream)``, fixed by :class:`StreamSampler`, so they do not depend on the
number of loader workers, and a run resumed at step ``s`` sees exactly the samples it would have seen.
HDF5 files are opened lazily inside each worker (``projsynth.dataset.shards.ShardReader`` reopens after fork).

A captured image of another size than the projected one (captured data) is resized to it and its
truth converted (:mod:`projreg.geometry.frames`), so batches hold one size.

Convention: ``img0`` = projected, ``img1`` = captured, ``[3, H, W]`` uint8 RGB (the network converts);
``flow`` ``[2, H, W]`` float32 projected -> captured; ``valid`` ``[H, W]`` bool.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from projsynth.dataset.shards import ShardReader
from projsynth.errors import ProjsynthError

from ..errors import ProjregError
from ..geometry.frames import frame_scale, resize_to, truth_to_projected_frame


@dataclass(frozen=True)
class Augment:
    """Augmentation settings; ``crop`` ``(h, w)`` or None keeps the full frame."""

    crop: tuple[int, int] | None = None
    flip: bool = True
    scale: tuple[float, float] = (0.8, 1.25)  # log-uniform, applied before the crop (with a crop only)
    photometric: bool = True


def open_readers(roots: list[Path]) -> list[ShardReader]:
    """One reader per dataset directory; a missing or corrupt manifest names the directory."""
    readers = []
    for root in roots:
        try:
            readers.append(ShardReader(Path(root)))
        except ProjsynthError as e:
            raise ProjregError(f"--data/--val {root}: {e}") from e
    return readers


class ShardDataset(Dataset):
    """All samples of one or more dataset directories, indexed ``(global index, augment seed)``."""

    def __init__(self, roots: list[Path], augment: Augment | None = None, *, batched: bool = True):
        """``batched=False``: samples are used one at a time (validation), so sizes may differ."""
        self.readers = open_readers(roots)
        self.offsets = np.cumsum([0] + [len(r) for r in self.readers])
        self.augment = augment
        sizes = {tuple(r.manifest["size"]) for r in self.readers}
        if batched and len(sizes) > 1 and (augment is None or augment.crop is None):
            raise ProjregError(f"datasets have different sizes {sorted(sizes)}; train with a crop")

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, item: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        index, aug_seed = item if isinstance(item, tuple) else (item, 0)
        j = int(np.searchsorted(self.offsets, index, side="right") - 1)
        try:
            s = self.readers[j].read(int(index - self.offsets[j]), with_params=False)
        except ProjsynthError as e:
            raise ProjregError(str(e)) from e
        img0, img1, flow, valid = s["projected"], s["captured"], s["flow"], s["valid"]
        if img1.shape != img0.shape:  # captured data: the network sees the camera frame at the projector's size
            flow, valid = truth_to_projected_frame(flow, valid, frame_scale(img0.shape, img1.shape))
            img1 = resize_to(img1, img0.shape)
        if self.augment is not None:
            rng = np.random.default_rng(aug_seed)
            img0, img1, flow, valid = augment_sample(img0, img1, flow, valid, self.augment, rng)
        return {
            "img0": torch.from_numpy(np.ascontiguousarray(img0.transpose(2, 0, 1))),  # uint8: a quarter of
            "img1": torch.from_numpy(np.ascontiguousarray(img1.transpose(2, 0, 1))),  # the bytes of float32
            "flow": torch.from_numpy(np.ascontiguousarray(flow.transpose(2, 0, 1))),
            "valid": torch.from_numpy(np.ascontiguousarray(valid)),
        }


def augment_sample(
    img0: np.ndarray, img1: np.ndarray, flow: np.ndarray, valid: np.ndarray, aug: Augment, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Jitter colours, rescale, flip and crop a pair and its flow together.

    Flips and crops keep the ground truth exact; rescaling resamples the flow bilinearly (exact for
    locally affine flow) and keeps only pixels whose four neighbours were valid.
    """
    if aug.photometric:
        img0, img1 = _jitter(img0, rng), _jitter(img1, rng)
    if aug.crop is not None:  # rescaling needs a crop to bring batches back to one size
        s = float(np.exp(rng.uniform(np.log(aug.scale[0]), np.log(aug.scale[1]))))
        s = max(s, aug.crop[0] / img0.shape[0], aug.crop[1] / img0.shape[1])  # never below the crop
        if abs(s - 1.0) > 1e-3:
            img0, img1, flow, valid = rescale(img0, img1, flow, valid, s)
    if aug.flip and rng.random() < 0.5:
        img0, img1, valid = img0[:, ::-1], img1[:, ::-1], valid[:, ::-1]
        flow = flow[:, ::-1] * np.array([-1.0, 1.0], np.float32)
    if aug.flip and rng.random() < 0.1:
        img0, img1, valid = img0[::-1], img1[::-1], valid[::-1]
        flow = flow[::-1] * np.array([1.0, -1.0], np.float32)
    if aug.crop is not None:
        img0, img1, flow, valid = crop(img0, img1, flow, valid, aug.crop, rng)
    return img0, img1, flow, valid


def _jitter(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = img.astype(np.float32)
    gain = rng.uniform(0.7, 1.3, size=3).astype(np.float32) * np.float32(rng.uniform(0.7, 1.3))
    mean = x.mean(axis=(0, 1), keepdims=True)
    x = (x - mean) * np.float32(rng.uniform(0.7, 1.3)) + mean * gain  # contrast, brightness and colour
    x = 255.0 * (np.clip(x, 0, 255) / 255.0) ** np.float32(rng.uniform(0.8, 1.25))
    return np.clip(x, 0, 255).astype(np.uint8)


def rescale(img0, img1, flow, valid, s: float):
    """Scale both images by ``s``: ``flow'(p) = s * flow(p / s)``."""
    h, w = valid.shape
    nh, nw = max(int(round(h * s)), 8), max(int(round(w * s)), 8)
    sx, sy = nw / w, nh / h
    img0 = cv2.resize(img0, (nw, nh), interpolation=cv2.INTER_LINEAR)
    img1 = cv2.resize(img1, (nw, nh), interpolation=cv2.INTER_LINEAR)
    # sample at the exact pre-image p / s of each new pixel centre (align corners of pixel centres)
    xs = (np.arange(nw, dtype=np.float32) + 0.5) / sx - 0.5
    ys = (np.arange(nh, dtype=np.float32) + 0.5) / sy - 0.5
    mx, my = np.meshgrid(np.clip(xs, 0, w - 1), np.clip(ys, 0, h - 1))
    f = cv2.remap(flow, mx, my, cv2.INTER_LINEAR) * np.array([sx, sy], np.float32)
    ok = cv2.erode(valid.astype(np.uint8), np.ones((2, 2), np.uint8), anchor=(0, 0), borderValue=0)
    v = cv2.remap(ok, np.floor(mx).astype(np.float32), np.floor(my).astype(np.float32), cv2.INTER_NEAREST) > 0
    # the camera frame shrinks with the image: drop flow that now lands outside it
    gy, gx = np.mgrid[0:nh, 0:nw]
    u, w_ = gx + f[..., 0], gy + f[..., 1]
    v &= (u >= 0) & (u <= nw - 1) & (w_ >= 0) & (w_ <= nh - 1)
    return img0, img1, np.where(v[..., None], f, 0).astype(np.float32), v


def crop(img0, img1, flow, valid, size: tuple[int, int], rng: np.random.Generator):
    """The same window of both images; flow values unchanged, valid where ``p + F`` stays inside."""
    ch, cw = size
    h, w = valid.shape
    if ch > h or cw > w:
        raise ProjregError(f"--crop {ch}x{cw} is larger than the data ({h}x{w}); lower it")
    y0, x0 = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    sl = (slice(y0, y0 + ch), slice(x0, x0 + cw))
    flow, valid = flow[sl], valid[sl].copy()
    gy, gx = np.mgrid[0:ch, 0:cw]
    u, v = gx + flow[..., 0], gy + flow[..., 1]
    valid &= (u >= 0) & (u <= cw - 1) & (v >= 0) & (v <= ch - 1)
    return img0[sl], img1[sl], np.where(valid[..., None], flow, 0).astype(np.float32), valid


class StreamSampler(Sampler):
    """An endless, resumable stream of ``(index, augment seed)``: epoch ``e`` visits
    ``permutation(seed, e)``; position ``n`` gets augment seed ``(seed, n)``.

    ``rank``/``world`` shard the stream for DistributedDataParallel (position ``n * world + rank``).
    """

    def __init__(self, n: int, seed: int, start: int = 0, rank: int = 0, world: int = 1):
        self.n, self.seed, self.start, self.rank, self.world = n, seed, start, rank, world

    def __iter__(self) -> Iterator[tuple[int, int]]:
        pos = self.start
        perm_epoch, perm = -1, None
        while True:
            g = pos * self.world + self.rank
            epoch, i = divmod(g, self.n)
            if epoch != perm_epoch:
                perm_epoch, perm = epoch, np.random.default_rng([self.seed, epoch]).permutation(self.n)
            yield int(perm[i]), int(np.random.SeedSequence([self.seed, g]).generate_state(1)[0])
            pos += 1
