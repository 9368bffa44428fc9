"""End-point-error metrics: pooled EPE, flow-magnitude buckets and outlier rates.

Convention: flows are forward, projected -> captured, ``(H, W, 2)`` in pixels, ``flow[y, x] = (u, v)``;
``valid`` is a bool ``(H, W)`` mask and only valid pixels are counted. Buckets use the magnitude of the
ground truth: ``s0-10`` (|gt| < 10), ``s10-40`` (10 <= |gt| <= 40), ``s40+`` (|gt| > 40). ``px1/px3/px5``
are the fractions of valid pixels with EPE > 1/3/5 px.

``epe`` and the buckets are pooled over every valid pixel of the set (GMFlow's convention), so a
large image counts more than a small one; ``image_epe`` is the mean of the per-image means. A metric
with no pixels behind it is ``None`` (JSON ``null``), never NaN.

Worst cases: ``pair_median`` and ``pair_p90`` are the median and the 90th percentile (linear
interpolation, numpy's default) of the per-image mean EPEs, ``worst_epe`` the largest of them and
``worst_id`` the id of that image (the first one on ties).

Claimed pixels: a method may say where its flow holds (``claimed``, a bool mask, e.g. the refinement's
confidence); ``claimed`` is the share of valid pixels it claims (pooled), ``claimed_mean`` the mean of
the per-image shares, and ``epe_claimed`` the EPE pooled over the valid pixels it claims. A method that
claims nothing is passed ``claimed=None`` and claims every pixel.

Example:
    >>> import numpy as np
    >>> gt = np.zeros((1, 2, 2), np.float32)
    >>> pred = np.array([[[3.0, 4.0], [0.0, 0.0]]], np.float32)
    >>> summarize(pred, gt, np.ones((1, 2), bool))["epe"]
    2.5
"""

from __future__ import annotations

import numpy as np

from ..errors import ProjregError

BUCKETS = ("s0-10", "s10-40", "s40+")
THRESHOLDS = (1, 3, 5)
KEYS = (
    "epe",
    *BUCKETS,
    *(f"px{t}" for t in THRESHOLDS),
    "image_epe",
    "pixels",
    "images",
    "pair_median",
    "pair_p90",
    "worst_epe",
    "worst_id",
    "claimed",
    "claimed_mean",
    "epe_claimed",
)


def epe_map(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-pixel end-point error ``|pred - gt|``.

    Args:
        pred: predicted flow ``(H, W, 2)``.
        gt: ground-truth flow ``(H, W, 2)``.

    Returns:
        ``(H, W)`` float64 Euclidean distance in pixels.
    """
    _check_flow("pred", pred)
    _check_flow("gt", gt)
    if pred.shape != gt.shape:
        raise ProjregError(f"pred shape {pred.shape} != gt shape {gt.shape}; pass flows of the same size")
    d = pred.astype(np.float64) - gt.astype(np.float64)  # [H, W, 2]
    return np.hypot(d[..., 0], d[..., 1])


def bucket_masks(gt: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean ``(H, W)`` masks of the three magnitude buckets of ``gt`` ``(H, W, 2)`` (they partition it)."""
    _check_flow("gt", gt)
    mag = np.hypot(gt[..., 0].astype(np.float64), gt[..., 1].astype(np.float64))  # [H, W]
    return {"s0-10": mag < 10, "s10-40": (mag >= 10) & (mag <= 40), "s40+": mag > 40}


class EPEAccumulator:
    """Running sums of EPE over a set of images; ``merge`` combines sets (groups, distributed ranks).

    Sums and counts are float64 / int64: pooled metrics are exact ratios of sums, so the result does
    not depend on the order or grouping in which images were added. An image with no valid pixel is
    counted in ``images`` but has no per-image mean.
    """

    def __init__(self) -> None:
        self.sums = np.zeros(1 + len(BUCKETS), np.float64)  # [all, s0-10, s10-40, s40+]
        self.counts = np.zeros(1 + len(BUCKETS), np.int64)
        self.outliers = np.zeros(len(THRESHOLDS), np.int64)  # pixels with EPE > 1, 3, 5
        self.image_epes: list[float] = []
        self.image_ids: list[str | None] = []  # parallel to image_epes
        self.image_claims: list[float] = []  # per image with a valid pixel: share of them claimed
        self.claimed_sum = 0.0  # EPE summed over claimed valid pixels
        self.claimed_count = 0
        self.images = 0

    def add(
        self,
        pred: np.ndarray,
        gt: np.ndarray,
        valid: np.ndarray,
        claimed: np.ndarray | None = None,
        image_id: str | None = None,
    ) -> None:
        """Accumulate one image.

        Args:
            pred: predicted flow ``(H, W, 2)``, projected -> captured, pixels.
            gt: ground-truth flow ``(H, W, 2)``, same convention.
            valid: bool ``(H, W)``; pixels where it is false are ignored.
            claimed: bool ``(H, W)``, the pixels where the method says its flow holds; None: all.
            image_id: the name reported as ``worst_id`` if this image is the worst.
        """
        epe = epe_map(pred, gt)
        valid = _mask("valid", valid, epe.shape)
        claimed = np.ones_like(valid) if claimed is None else _mask("claimed", claimed, epe.shape)
        e = epe[valid]  # [N]
        ec = epe[valid & claimed]  # [M]
        self.claimed_sum += ec.sum()
        self.claimed_count += ec.size
        self.sums[0] += e.sum()
        self.counts[0] += e.size
        for i, mask in enumerate(bucket_masks(gt).values(), start=1):
            eb = epe[mask & valid]
            self.sums[i] += eb.sum()
            self.counts[i] += eb.size
        for i, t in enumerate(THRESHOLDS):
            self.outliers[i] += np.count_nonzero(e > t)
        if e.size:
            self.image_epes.append(float(e.mean()))
            self.image_ids.append(image_id)
            self.image_claims.append(ec.size / e.size)
        self.images += 1

    def merge(self, other: EPEAccumulator) -> EPEAccumulator:
        """Add ``other``'s images to this accumulator (in place) and return it."""
        self.sums += other.sums
        self.counts += other.counts
        self.outliers += other.outliers
        self.image_epes.extend(other.image_epes)
        self.image_ids.extend(other.image_ids)
        self.image_claims.extend(other.image_claims)
        self.claimed_sum += other.claimed_sum
        self.claimed_count += other.claimed_count
        self.images += other.images
        return self

    def result(self) -> dict[str, float | int | None]:
        """Metrics of everything added, keys ``KEYS``; ``None`` where no pixel (or image) contributes."""
        n = int(self.counts[0])
        out: dict[str, float | int | None] = {"epe": _ratio(self.sums[0], n)}
        for i, name in enumerate(BUCKETS, start=1):
            out[name] = _ratio(self.sums[i], int(self.counts[i]))
        for i, t in enumerate(THRESHOLDS):
            out[f"px{t}"] = _ratio(float(self.outliers[i]), n)
        out["image_epe"] = _ratio(sum(self.image_epes), len(self.image_epes))
        out["pixels"] = n
        out["images"] = self.images
        pairs = np.asarray(self.image_epes, np.float64)  # [images with a valid pixel]
        worst = int(np.argmax(pairs)) if pairs.size else None
        out["pair_median"] = float(np.median(pairs)) if pairs.size else None
        out["pair_p90"] = float(np.percentile(pairs, 90)) if pairs.size else None
        out["worst_epe"] = None if worst is None else float(pairs[worst])
        out["worst_id"] = None if worst is None else self.image_ids[worst]
        out["claimed"] = _ratio(float(self.claimed_count), n)
        out["claimed_mean"] = _ratio(sum(self.image_claims), len(self.image_claims))
        out["epe_claimed"] = _ratio(self.claimed_sum, self.claimed_count)
        return out


def summarize(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> dict[str, float | int | None]:
    """Metrics of one image: ``EPEAccumulator`` over that image alone (see its ``result``)."""
    acc = EPEAccumulator()
    acc.add(pred, gt, valid)
    return acc.result()


def _ratio(total: float, count: int) -> float | None:
    return float(total) / count if count else None


def _mask(name: str, mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.dtype != np.bool_ or mask.shape != shape:
        raise ProjregError(f"{name} must be a bool array of shape {shape}, got {mask.dtype} {mask.shape}")
    return mask


def _check_flow(name: str, flow: np.ndarray) -> None:
    if not isinstance(flow, np.ndarray) or flow.ndim != 3 or flow.shape[2] != 2:
        shape = getattr(flow, "shape", type(flow).__name__)
        raise ProjregError(f"{name} must be a flow array of shape (H, W, 2), got {shape}")


def sample_indices(n: int, limit: int | None) -> list[int]:
    """All of ``range(n)``, or ``limit`` indices spread evenly over it (first and last included).

    Example:
        >>> sample_indices(16, 4)
        [0, 5, 10, 15]
    """
    if limit is not None and limit < 1:
        raise ProjregError(f"--limit must be >= 1, got {limit}")
    if limit is None or limit >= n:
        return list(range(n))
    return [int(i) for i in np.linspace(0, n - 1, limit).astype(int)]
