"""Decode the paper's dot protocol: ``on``, ``off`` and one photo per bit of each dot's index.

A dot is a blob of ``on - off`` (smoothed, above a noise-relative threshold). Its camera position is
the centroid of a soft mask: ``on - off``, smoothed (``SMOOTH_PX``: a sharp edge point-sampled by the
camera aliases; smoothed, the centroid of the samples is that of the signal: 0.08 -> 0.014 px mean on
a flat surface), divided by its largest value within 2 px (the lit level of the nearby dot interior,
so albedo texture coarser than that cancels), 0 below 0.1, 1 above 0.9, linear in between: the
interior's albedo does not pull the centre, only the edge ramp locates it. Its index is read bit by bit as the ratio
``(bit - off) / (on - off)`` summed over the blob (1 lit, 0 dark: ambient light and albedo cancel).

A dot is either right or absent. Dropped: a blob touching the frame border (truncated), a bit whose
ratio lies between 0.25 and 0.75, an index outside the grid or found twice, an area far from the
other dots', a dot that no grid neighbour confirms (a decoded neighbour whose camera distance
matches the grid spacing at the median camera scale: a wrong index lands far from its neighbours),
and a dot at the decoded region's edge whose area is less than a whole dot's at the local scale of
its neighbours (cut by a silhouette or an occluding edge, its centroid would be its visible part's).

Convention: the result is a flow on the projector grid, valid only at decoded dot centres.
"""

from __future__ import annotations

import cv2
import numpy as np

from .patterns import PatternSet, dot_centres

MIN_CONTRAST = 0.02  # on - off, of full scale
NOISE_SIGMAS = 6.0  # detection threshold in noise standard deviations of the smoothed difference
SMOOTH_PX = 1.0  # Gaussian smoothing before the centroid: the photo point-samples a sharp edge (aliasing)


def decode_dots(patterns: PatternSet, stack: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(flow, valid, stats)`` from the photos ``stack`` (pattern names without ``NN-``), see the module."""
    h, w = patterns.size
    off = stack["off"].astype(np.float64)
    diff = stack["on"] - off
    labels, n = _blobs(diff)
    flat, d = labels.ravel(), diff.ravel()
    index, ambiguous = _read_bits(stack, off.ravel(), flat, d, n, patterns.params["bits"])
    cx, cy, total = _centroids(stack, off, labels, n, index, patterns.params["bits"])
    centres = dot_centres(patterns)
    keep = (total > 0) & ~ambiguous & (index < len(centres)) & ~_touches_border(labels, n)
    keep[0] = False  # the background
    if keep.any():
        med = np.median(total[keep])
        keep &= (total >= 0.25 * med) & (total <= 4 * med)
    counts = np.bincount(index[keep], minlength=len(centres))
    keep &= counts[np.minimum(index, len(centres) - 1)] == 1  # an index seen twice: neither is trusted
    found = {int(index[k]): (cx[k], cy[k]) for k in np.nonzero(keep)[0]}
    area = {int(index[k]): total[k] for k in np.nonzero(keep)[0]}
    gx = patterns.params["grid"][1]
    found = _confirmed(found, centres, gx)
    found = _whole(found, area, centres, gx, _disc_pixels(patterns.params["radius"]))
    flow, valid = np.zeros((h, w, 2), np.float32), np.zeros((h, w), bool)
    for i, (x, y) in found.items():
        X, Y = centres[i]
        flow[Y, X], valid[Y, X] = (x - X, y - Y), True
    return flow, valid, {"dots": len(centres), "dots_decoded": len(found), "blobs": int(n - 1)}


def _centroids(stack: dict, off: np.ndarray, labels: np.ndarray, n: int, index: np.ndarray, bits: int):  # noqa: ANN202
    """Per blob, the soft-mask centroid ``(cx, cy)`` summed over every photo the dot is lit in (``on``
    and the bits of its index: about ``1 + bits / 2`` looks at the same edge, noise averaged), and the
    mask's total (its area in ``on``-photo units)."""
    flat = labels.ravel()
    ys, xs = np.divmod(np.arange(flat.size), labels.shape[1])
    weight = np.zeros(flat.size)
    for name, lit in [("on", np.ones(n, bool)), *((f"bit{b}", (index >> b) & 1 == 1) for b in range(bits))]:
        smooth = cv2.GaussianBlur(stack[name] - off, (0, 0), SMOOTH_PX)
        level = cv2.dilate(smooth, np.ones((5, 5), np.uint8)).ravel()  # the lit level nearby
        mask = np.clip((smooth.ravel() / np.maximum(level, 1e-12) - 0.1) / 0.8, 0.0, 1.0)
        weight += mask * (lit[flat] & (flat > 0))
    total = np.bincount(flat, weight, n)
    cx = np.bincount(flat, weight * xs, n) / np.maximum(total, 1e-12)
    cy = np.bincount(flat, weight * ys, n) / np.maximum(total, 1e-12)
    return cx, cy, total / (1 + np.array([bin(int(i)).count("1") for i in index]))


def _blobs(diff: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected blobs of the smoothed difference above ``max(MIN_CONTRAST, NOISE_SIGMAS x noise)``."""
    smooth = cv2.GaussianBlur(diff, (0, 0), 1.0)
    residual = smooth - cv2.GaussianBlur(smooth, (0, 0), 3.0)
    noise = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    threshold = max(MIN_CONTRAST, NOISE_SIGMAS * noise)
    n, labels = cv2.connectedComponents((smooth > threshold).astype(np.uint8), connectivity=8)
    return labels, n


def _read_bits(stack: dict, off: np.ndarray, flat: np.ndarray, d: np.ndarray, n: int, bits: int):  # noqa: ANN202
    """Per blob: the index (bit ``b`` = ratio >= 0.5) and whether any bit's ratio was ambiguous."""
    inside = flat > 0
    lab, denom = flat[inside], np.maximum(np.bincount(flat[inside], d[inside], n), 1e-12)
    index, ambiguous = np.zeros(n, np.int64), np.zeros(n, bool)
    for b in range(bits):
        ratio = np.bincount(lab, stack[f"bit{b}"].ravel()[inside] - off[inside], n) / denom
        ambiguous |= (ratio > 0.25) & (ratio < 0.75)
        index |= (ratio >= 0.5).astype(np.int64) << b
    return index, ambiguous


def _touches_border(labels: np.ndarray, n: int) -> np.ndarray:
    touching = np.zeros(n, bool)
    touching[np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))] = True
    return touching


def _disc_pixels(radius: float) -> int:
    r = int(np.ceil(radius))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    return int(np.count_nonzero(dx * dx + dy * dy <= radius * radius))


def _whole(found: dict, area: dict, centres: np.ndarray, gx: int, disc: int) -> dict:
    """Drop the dots at the decoded region's edge (a grid neighbour missing) whose blob is smaller than a
    whole dot there: ``disc`` projector pixels times the local area scale ``|det J|`` of the projector
    -> camera map (``J`` from the decoded grid neighbours), relative to the median over all dots.

    A dot cut by a silhouette, an occluding edge or a shadow keeps the centroid of its visible part
    (off by up to its radius) and usually all of its bits; such cuts happen where neighbours are
    missing. Kept there: 0.88x to 1.25x of the median (whole dots spread about +-10%: a dot cut at a
    cylinder's silhouette measured 0.86x). Dots without two decoded neighbours across are dropped.
    """
    ratio = {}
    for i, xy in found.items():
        columns = []
        for step in (1, gx):  # along the grid's x, then its y
            diffs = [
                (np.subtract(found[j], xy) * np.sign(j - i)) / np.hypot(*(centres[j] - centres[i]))
                for j in (i - step, i + step)
                if j in found and (step == gx or j // gx == i // gx)
            ]
            columns.append(np.mean(diffs, axis=0) if diffs else None)
        if columns[0] is not None and columns[1] is not None:
            ratio[i] = area[i] / (disc * abs(columns[0][0] * columns[1][1] - columns[0][1] * columns[1][0]))
    if not ratio:
        return {}
    typical = float(np.median(list(ratio.values())))
    kept = {}
    for i, r in ratio.items():
        inner = all(j in found for j in _grid_neighbours(i, gx, len(centres)))
        if inner or 0.88 <= r / typical <= 1.25:
            kept[i] = found[i]
    return kept


def _grid_neighbours(i: int, gx: int, n: int) -> list[int]:
    """The 4-neighbours of dot ``i`` that exist in a grid of ``n`` dots, ``gx`` per row."""
    out = [j for j in (i - gx, i + gx) if 0 <= j < n]
    return out + [j for j in (i - 1, i + 1) if 0 <= j < n and j // gx == i // gx]


def _confirmed(found: dict[int, tuple[float, float]], centres: np.ndarray, gx: int) -> dict:
    """The dots with at least one 4-neighbour in the grid at a camera distance that fits the grid.

    The camera scale is the median ratio camera distance / projector distance over all decoded
    neighbour pairs; a pair fits when its ratio is within a factor 2 of it.
    """
    pairs = [(i, j) for i in found for j in (i + 1, i + gx) if j in found and (j != i + 1 or j % gx)]
    if not pairs:
        return {}
    ratio = {
        p: np.hypot(*np.subtract(found[p[0]], found[p[1]])) / np.hypot(*(centres[p[0]] - centres[p[1]])) for p in pairs
    }
    scale = float(np.median(list(ratio.values())))
    good = {i for p, r in ratio.items() if scale / 2 <= r <= scale * 2 for i in p}
    return {i: xy for i, xy in found.items() if i in good}
