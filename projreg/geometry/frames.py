"""Pairs whose captured image is not the projected image's size (real rigs: camera != projector).

Every registration method here (the network, the refinement, the classical baselines) takes two
images of one size. A captured image of another size is resized to the projected image's size
(``cv2.INTER_AREA`` when shrinking, ``INTER_LINEAR`` when enlarging), the method runs on that pair,
and its flow is brought back to the captured image's pixels. With pixel centres at integers, the
resized image's pixel ``c'`` is the captured image's ``c = (c' + 0.5) / s - 0.5`` per axis
(``s = projected size / captured size``), so

    flow(p) = (p + flow'(p) + 0.5) / s - 0.5 - p.

Ground truth goes the other way for training (:func:`truth_to_projected_frame`). Flows are always
on the projected grid; only their values are in captured pixels.

A whole pair is shrunk the same way for a faster run (:func:`shrink`: the network's ``--max-side``,
the fast path's refinement) and the flow resized back onto the pair's grid (:func:`resize_flow`).

Example:
    >>> import numpy as np
    >>> f = flow_to_captured(np.zeros((2, 2, 2), np.float32), (0.5, 0.5))
    >>> f[1, 1].tolist()  # pixel (1, 1) of a half-size view is (2.5, 2.5) of the full image
    [1.5, 1.5]
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import cv2
import numpy as np

from ..prediction import Prediction
from .warp import pixel_maps

Register = Callable[[np.ndarray, np.ndarray], "np.ndarray | Prediction"]


def frame_scale(projected_shape: tuple[int, ...], captured_shape: tuple[int, ...]) -> tuple[float, float]:
    """``(sx, sy)``: projected size over captured size per axis (1, 1 for a same-size pair)."""
    return projected_shape[1] / captured_shape[1], projected_shape[0] / captured_shape[0]


def resize_to(image: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``image`` resized to ``shape[:2]`` (area averaging when it shrinks)."""
    h, w = shape[:2]
    if image.shape[:2] == (h, w):
        return image
    shrink = h * w < image.shape[0] * image.shape[1]
    return cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def shrink(image: np.ndarray, max_side: int) -> np.ndarray:
    """``image`` with its longer side shrunk to ``max_side`` (``cv2.INTER_AREA``, aspect kept,
    ``w' = round(W s)``, ``h' = round(H s)``); unchanged when it already fits."""
    h, w = image.shape[:2]
    s = max_side / max(h, w)
    if s >= 1:
        return image
    return cv2.resize(image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)


def resize_flow(flow: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A flow computed on resized images on the ``shape[:2]`` grid instead, in its pixels: bilinear
    (``cv2.INTER_LINEAR``), u scaled by ``W / w'`` and v by ``H / h'`` (either direction)."""
    h, w = shape[:2]
    if flow.shape[:2] == (h, w):
        return flow
    small_h, small_w = flow.shape[:2]
    big = cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR)
    return (big * np.array([w / small_w, h / small_h], np.float32)).astype(np.float32)


def _grid(h: int, w: int) -> np.ndarray:
    return np.stack(pixel_maps(h, w), -1)  # [H, W, 2] (x, y)


def flow_to_captured(flow: np.ndarray, scale: tuple[float, float]) -> np.ndarray:
    """A flow into the resized captured frame -> the same flow in the captured image's pixels."""
    if scale == (1.0, 1.0):
        return flow
    s = np.array(scale, np.float32)
    p = _grid(*flow.shape[:2])
    return ((p + flow + 0.5) / s - 0.5 - p).astype(np.float32)


def truth_to_projected_frame(
    flow: np.ndarray, valid: np.ndarray, scale: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth in captured pixels -> in the captured image resized to the projected size.

    Returns:
        ``(flow', valid')``: valid where it was and ``p + flow'`` stays inside the resized frame.
    """
    if scale == (1.0, 1.0):
        return flow, valid
    h, w = valid.shape
    s = np.array(scale, np.float32)
    p = _grid(h, w)
    target = (p + flow + 0.5) * s - 0.5
    inside = (target[..., 0] >= 0) & (target[..., 0] <= w - 1) & (target[..., 1] >= 0) & (target[..., 1] <= h - 1)
    valid = valid & inside
    return np.where(valid[..., None], target - p, 0).astype(np.float32), valid


def register_any_size(method: Register, projected: np.ndarray, captured: np.ndarray) -> np.ndarray | Prediction:
    """``method(projected, captured)`` for a pair of any two sizes: its flow (or its
    :class:`~projreg.prediction.Prediction`'s flow) in captured pixels (module docstring)."""
    if captured.shape[:2] == projected.shape[:2]:
        return method(projected, captured)
    out = method(projected, resize_to(captured, projected.shape))
    scale = frame_scale(projected.shape, captured.shape)
    if isinstance(out, Prediction):
        return replace(out, flow=flow_to_captured(out.flow, scale))
    return flow_to_captured(out, scale)
