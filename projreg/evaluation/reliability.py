"""What a confidence level means: the share of pixels within 1 px and 3 px of the truth, per band.

A refined method gives every pixel a confidence in [0, 1] (:mod:`projreg.refine.confidence`); its claim
is the pixels at ``CONFIDENT`` or more on a registered pair. An operator who wants another threshold
(``projreg compensate --min-confidence``) needs to know what a level buys: :class:`ReliabilityAccumulator`
pools, over the valid pixels of the registered pairs of a set, how many fall in each band of
``BANDS`` and how many of those are within 1 px and 3 px of the truth (the page's reliability table).
Pairs reported as not registered are left out: whatever their confidence, they claim nothing and are
projected as they are.

Example:
    >>> import numpy as np
    >>> acc = ReliabilityAccumulator()
    >>> gt = np.zeros((1, 2, 2), np.float32)
    >>> flow = np.array([[[0.5, 0.0], [2.0, 0.0]]], np.float32)
    >>> acc.add(flow, gt, np.ones((1, 2), bool), np.array([[0.95, 0.2]], np.float32))
    >>> [(b["band"], b["pixels"], b["within1"]) for b in acc.result() if b["pixels"]]
    [('0.1-0.3', 1, 0.0), ('0.9-1', 1, 1.0)]
"""

from __future__ import annotations

import numpy as np

BANDS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0)  # band i holds confidences in [BANDS[i], BANDS[i + 1]), the last one 1


class ReliabilityAccumulator:
    """Per confidence band: valid pixels, and of those the ones within 1 px and 3 px (module docstring)."""

    def __init__(self) -> None:
        n = len(BANDS) - 1
        self.pixels = np.zeros(n, np.int64)
        self.within = np.zeros((2, n), np.int64)  # [within 1 px, within 3 px] x bands

    def add(self, flow: np.ndarray, gt: np.ndarray, valid: np.ndarray, confidence: np.ndarray) -> None:
        """One registered pair: flows ``(H, W, 2)`` projected -> captured (px), ``valid`` bool and
        ``confidence`` float ``(H, W)``."""
        epe = np.linalg.norm(np.asarray(flow, np.float64) - gt, axis=-1)[valid]  # [N]
        band = np.clip(np.searchsorted(BANDS, np.asarray(confidence)[valid], side="right") - 1, 0, len(BANDS) - 2)
        n = len(BANDS) - 1
        self.pixels += np.bincount(band, minlength=n)
        for row, t in enumerate((1.0, 3.0)):
            self.within[row] += np.bincount(band[epe <= t], minlength=n)

    def result(self) -> list[dict]:
        """One dict per band: ``band`` (``"lo-hi"``), ``pixels``, ``share`` (of all the pixels counted),
        ``within1`` and ``within3`` (shares of the band's pixels; None for an empty band)."""
        total = int(self.pixels.sum())
        out = []
        for i, count in enumerate(self.pixels):
            count = int(count)
            out.append(
                {
                    "band": f"{BANDS[i]:g}-{BANDS[i + 1]:g}",
                    "pixels": count,
                    "share": count / total if total else None,
                    "within1": int(self.within[0, i]) / count if count else None,
                    "within3": int(self.within[1, i]) / count if count else None,
                }
            )
        return out
