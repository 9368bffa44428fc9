"""Evaluate a model on shard samples: pooled EPE, buckets and outlier rates (``metrics.EPEAccumulator``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from ..evaluation.metrics import EPEAccumulator, sample_indices
from .data import ShardDataset


@torch.no_grad()
def predict_flow(model: torch.nn.Module, img0: np.ndarray, img1: np.ndarray, device: torch.device) -> np.ndarray:
    """Flow ``(H, W, 2)`` float32 projected -> captured for one uint8 RGB pair ``(H, W, 3)``."""
    t0 = torch.from_numpy(np.ascontiguousarray(img0.transpose(2, 0, 1))).float()[None].to(device)
    t1 = torch.from_numpy(np.ascontiguousarray(img1.transpose(2, 0, 1))).float()[None].to(device)
    return model(t0, t1)[-1][0].permute(1, 2, 0).float().cpu().numpy()


@torch.no_grad()
def evaluate(
    model: torch.nn.Module,
    dataset: ShardDataset,
    *,
    device: torch.device,
    limit: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Pooled metrics of the last prediction over ``limit`` samples spread evenly (all if None);
    ``progress(done, total)`` before the first sample and after each."""
    model.eval()
    acc = EPEAccumulator()
    indices = sample_indices(len(dataset), limit)
    for done, i in enumerate(indices):
        if progress:
            progress(done, len(indices))
        s = dataset[i]
        pred = model(s["img0"][None].to(device), s["img1"][None].to(device))[-1][0]
        acc.add(pred.permute(1, 2, 0).float().cpu().numpy(), s["flow"].permute(1, 2, 0).numpy(), s["valid"].numpy())
    if progress:
        progress(len(indices), len(indices))
    return acc.result()
