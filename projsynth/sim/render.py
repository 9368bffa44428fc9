"""Render one sample: the captured image and the exact flow for a projected image on a scene.

Convention: ``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at camera pixel
``(x + u, y + v)``; ``flow`` is 0 where ``valid`` is false. The captured image at camera pixel ``q``
is the projected image sampled bilinearly at exactly ``backward(q)``, so sampling the captured
image at ``p + flow(p)`` gives back the projected image at ``p`` (up to interpolation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..utils.jit import jit
from .photometric import composite
from .scene import MISS, NEAR_EDGE, OCCLUDED, REASONS, Scene, backward, forward, pixel_grid

# Valid pixels this close (projector px) to an occluded or missed one are dropped: there the camera's
# pixels straddle the occluding surface or the silhouette, so the captured image mixes unrelated
# content and cannot show the (still exact) correspondence.
EDGE_MARGIN_PX = 3


@dataclass(frozen=True)
class Rendered:
    captured: np.ndarray  # (H, W, 3) uint8
    flow: np.ndarray  # (H, W, 2) float32, projected -> captured
    valid: np.ndarray  # (H, W) bool
    stats: dict  # valid share, invalid-reason counts, flow magnitude summary, corner shifts


def alpha_field(shape: tuple[int, int], mean: float, var: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth transparency of the projected content, ``(H, W)`` float32 in [0, 1]."""
    coarse = rng.uniform(-1.0, 1.0, size=(4, 5)).astype(np.float32)
    smooth = cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return np.clip(mean + var * smooth, 0.0, 1.0)


def render(
    projected: np.ndarray,
    background: np.ndarray,
    scene: Scene,
    photometry: dict[str, float],
    blend: str,
    rng: np.random.Generator,
    *,
    exposure: Sequence[Scene] = (),
    noise: np.random.Generator | None = None,
) -> Rendered:
    """Project ``projected`` through ``scene`` onto ``background`` and record the ground truth.

    Args:
        projected: ``(H, W, 3)`` uint8 projector frame buffer (the projector lens's frame).
        background: ``(Hc, Wc, 3)`` uint8 scene as the camera sees it (the camera lens's frame).
        scene: geometry.
        photometry: drawn parameters for :func:`~projsynth.sim.photometric.composite`.
        blend: ``"paper"`` or ``"physical"``.
        rng: the sample's generator, used for the transparency field and the noise.
        exposure: motion blur: the scenes of the rig's poses over the exposure; the photo is the mean
            of their photos (each with the same noise, so the mean has one photo's noise), rounded.
            The ground truth stays ``scene``'s (the mid-exposure pose). Empty: ``scene``'s photo.
        noise: the generator of the sensor noise (None: ``rng``, continuing after the transparency).
    """
    flow, valid, reason = ground_truth(scene)
    alpha = alpha_field(projected.shape[:2], photometry["alpha"], photometry["alpha_var"], rng)
    view = camera_view(scene)
    views = [camera_view(sub) for sub in exposure] or [view]
    captured = expose(projected, alpha, views, background, photometry, blend, rng if noise is None else noise)
    return Rendered(captured, flow, valid, _stats(scene, reason, flow, valid, view[1]))


def ground_truth(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exact flow of every projector pixel of ``scene``.

    Returns:
        ``(flow, valid, reason)``: ``(H, W, 2)`` float32 in camera pixels (0 where not valid),
        ``(H, W)`` bool and ``(H, W)`` uint8 bit flags of ``scene.REASONS`` (0 where valid), on the
        projector's ``H x W`` grid.
    """
    h, w = scene.projector.height, scene.projector.width
    fm = forward(scene, pixel_grid(h, w))
    reason = fm.reason.reshape(h, w).copy()
    edges = ((reason & (OCCLUDED | MISS)) > 0).astype(np.uint8)
    if edges.any():
        k = 2 * EDGE_MARGIN_PX + 1
        near = cv2.dilate(edges, np.ones((k, k), np.uint8)) > 0
        reason[near & (reason == 0)] = NEAR_EDGE
    valid = reason == 0
    return _flow(fm.uv, valid.ravel(), h, w), valid, reason


def camera_view(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The backward map of every camera pixel, ``(xy, lit)`` as :func:`~projsynth.sim.scene.backward` returns it."""
    return backward(scene, pixel_grid(scene.camera.height, scene.camera.width))


def photograph(
    projected: np.ndarray,
    alpha: np.ndarray,
    view: tuple[np.ndarray, np.ndarray],
    background: np.ndarray,
    photometry: dict[str, float],
    blend: str,
    rng: np.random.Generator,
) -> np.ndarray:
    """The camera's photo of ``projected`` (transparency ``alpha``, ``(H, W)`` in [0, 1]) lighting the
    scene whose camera view is ``view`` (:func:`camera_view`); ``rng`` draws the sensor noise only.

    Returns:
        ``(Hc, Wc, 3)`` uint8, the size of ``background``.
    """
    if projected.ndim == 2:
        projected = np.repeat(projected[..., None], 3, axis=2)
    rgba = _with_alpha(np.ascontiguousarray(projected), alpha)
    return composite(blend, rgba, view[0], view[1], background, photometry, rng)


def expose(
    projected: np.ndarray,
    alpha: np.ndarray,
    views: Sequence[tuple[np.ndarray, np.ndarray]],
    background: np.ndarray,
    photometry: dict[str, float],
    blend: str,
    noise: np.random.Generator,
) -> np.ndarray:
    """:func:`photograph` over an exposure: the mean of one photo per camera view (the rig's poses over
    the exposure), rounded to uint8; every photo draws the same noise from ``noise``, so the mean has
    one photo's noise. One view: its photo, exactly."""
    if len(views) == 1:
        return photograph(projected, alpha, views[0], background, photometry, blend, noise)
    state = noise.bit_generator.state
    photos = []
    for view in views:
        noise.bit_generator.state = state
        photos.append(photograph(projected, alpha, view, background, photometry, blend, noise))
    return np.rint(np.mean(photos, axis=0)).astype(np.uint8)


@jit
def _with_alpha(rgb, alpha):  # noqa: ANN001, ANN202
    """``(H, W, 4)`` uint8: the image and ``round(255 * alpha)`` (alpha in [0, 1]) as its fourth channel."""
    h, w = rgb.shape[0], rgb.shape[1]
    out = np.empty((h, w, 4), np.uint8)
    for y in range(h):
        for x in range(w):
            out[y, x, 0], out[y, x, 1], out[y, x, 2] = rgb[y, x, 0], rgb[y, x, 1], rgb[y, x, 2]
            out[y, x, 3] = np.uint8(np.rint(alpha[y, x] * np.float32(255.0)))
    return out


@jit
def _flow(uv, valid, h, w):  # noqa: ANN001, ANN202
    """``(H, W, 2)`` float32 flow ``uv - p`` on the pixel grid, 0 where not valid."""
    flow = np.zeros((h, w, 2), np.float32)
    for i in range(h * w):
        if valid[i]:
            y, x = i // w, i % w
            flow[y, x, 0], flow[y, x, 1] = uv[0, i] - x, uv[1, i] - y
    return flow


def _stats(scene: Scene, reason: np.ndarray, flow: np.ndarray, valid: np.ndarray, lit: np.ndarray) -> dict:
    mag = np.hypot(flow[..., 0], flow[..., 1])[valid]
    h, w = valid.shape
    corners = np.array([[0.0, w - 1, w - 1, 0.0], [0.0, 0.0, h - 1, h - 1]])
    cm = forward(scene, corners)
    shifts = np.where(cm.valid, np.hypot(*(cm.uv - corners)), np.nan)
    return {
        "valid_share": float(valid.mean()),
        "lit_share": float(lit.mean()),
        "invalid_pixels": {k: int(np.count_nonzero(reason & bit)) for k, bit in REASONS.items()},
        "flow_median": float(np.median(mag)) if mag.size else None,
        "flow_max": float(mag.max()) if mag.size else None,
        # the paper's homography parametrisation: how far each projector corner moves (px)
        "corner_shift_px": [None if np.isnan(s) else round(float(s), 3) for s in shifts],
    }
