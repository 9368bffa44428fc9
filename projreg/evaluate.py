"""Evaluate a model on shard samples: pooled EPE, buckets and outlier rates (``metrics.EPEAccumulator``)."""

from __future__ import annotations

import numpy as np
import torch

from .data import ShardDataset
from .metrics import EPEAccumulator


@torch.no_grad()
def predict_flow(model: torch.nn.Module, img0: np.ndarray, img1: np.ndarray, device: torch.device) -> np.ndarray:
    """Flow ``(H, W, 2)`` float32 projected -> captured for one uint8 RGB pair ``(H, W, 3)``."""
    t0 = torch.from_numpy(np.ascontiguousarray(img0.transpose(2, 0, 1))).float()[None].to(device)
    t1 = torch.from_numpy(np.ascontiguousarray(img1.transpose(2, 0, 1))).float()[None].to(device)
    return model(t0, t1)[-1][0].permute(1, 2, 0).float().cpu().numpy()


@torch.no_grad()
def evaluate(model: torch.nn.Module, dataset: ShardDataset, *, device: torch.device, limit: int | None = None) -> dict:
    """Pooled metrics of the last prediction over the first ``limit`` samples (all if None)."""
    model.eval()
    acc = EPEAccumulator()
    n = len(dataset) if limit is None else min(limit, len(dataset))
    for i in np.linspace(0, len(dataset) - 1, n).astype(int) if n < len(dataset) else range(n):
        s = dataset[int(i)]
        pred = model(s["img0"][None].to(device), s["img1"][None].to(device))[-1][0]
        acc.add(pred.permute(1, 2, 0).float().cpu().numpy(), s["flow"].permute(1, 2, 0).numpy(), s["valid"].numpy())
    return acc.result()
