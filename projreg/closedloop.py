"""Judge a flow by what the camera finally sees: compensate, re-render, compare (``bench --compensation``).

For a generated sample, the desired camera view is the sample's projected picture placed in the camera
frame (:func:`projreg.compensate.compensate`'s convention: the picture spans the camera frame). Each
method's flow pre-warps it; the pre-warped projector image is photographed through the sample's own
scene, photometry and sensor noise (:class:`projsynth.rerender.Rerenderer`); so is the pre-warp by the
ground-truth flow, and the content projected as it is (the ``uncompensated`` row).

``comp_psnr`` / ``comp_ssim`` compare a method's camera view with the ground-truth compensation's
view over the **compared region**: camera pixels lit by the projector whose projector pixel is valid
in the ground truth (the surface the true compensation covers), eroded by 2 px so that the
silhouette's antialiasing does not count. Both views carry the same noise, so the difference is the
geometry. SSIM is scikit-image's (Gaussian window, sigma 1.5, on each RGB channel), averaged over
the region; PSNR is over the region's pixels and channels (peak 255). Per row: means over samples.

Example of the region rule: a projector pixel that misses the surface lights no camera pixel, so
errors there cannot be seen and do not count; a flow error inside a flat-coloured area moves flat
colour onto flat colour and costs little PSNR, while the same error on texture costs a lot.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from projsynth import ProjsynthError
from projsynth.rerender import Rerenderer, View

from . import ProjregError
from .compensate import compensate

UNCOMPENSATED = "uncompensated"
REGION_ERODE_PX = 2


class ClosedLoop:
    """Per sample: photograph each method's compensation and score it against the ground truth's."""

    def __init__(self, data: Path):
        try:
            self.rerenderer = Rerenderer(Path(data))
        except ProjsynthError as e:
            raise ProjregError(f"--compensation: {e}") from e

    def score(self, k: int, sample: dict, flows: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
        """``{method: {comp_psnr, comp_ssim}}`` for sample ``k`` (its reader dict), plus ``uncompensated``.

        Args:
            flows: each method's forward flow ``(H, W, 2)`` in captured pixels.
        """
        content = sample["projected"]
        camera = sample["captured"].shape
        images = [compensate(content, sample["flow"], sample["valid"], camera_size=camera[:2]), content]
        images += [compensate(content, f, np.isfinite(f).all(axis=2), camera_size=camera[:2]) for f in flows.values()]
        try:
            views = self.rerenderer.views(k, images)
        except ProjsynthError as e:
            raise ProjregError(f"--compensation: sample {k}: {e}") from e
        region = compared_region(views[0], sample["valid"])
        names = [UNCOMPENSATED, *flows]
        return {name: view_scores(v.image, views[0].image, region) for name, v in zip(names, views[1:], strict=True)}


def compared_region(truth_view: View, valid: np.ndarray) -> np.ndarray:
    """Camera pixels lit by the projector at a projector pixel valid in the ground truth, eroded."""
    h, w = valid.shape
    x = np.clip(np.rint(truth_view.source[..., 0]), 0, w - 1).astype(np.int64)
    y = np.clip(np.rint(truth_view.source[..., 1]), 0, h - 1).astype(np.int64)
    region = truth_view.lit & valid[y, x]
    k = 2 * REGION_ERODE_PX + 1
    return cv2.erode(region.astype(np.uint8), np.ones((k, k), np.uint8), borderValue=0) > 0


def view_scores(view: np.ndarray, reference: np.ndarray, region: np.ndarray) -> dict[str, float]:
    """PSNR (dB) and mean SSIM of ``view`` against ``reference`` over ``region`` (None: empty region)."""
    if not region.any():
        return {"comp_psnr": None, "comp_ssim": None}
    d = view.astype(np.float64)[region] - reference.astype(np.float64)[region]
    mse = float(np.mean(d * d))
    psnr = 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)  # identical views: capped, never inf
    _, ssim = structural_similarity(
        view,
        reference,
        channel_axis=2,
        data_range=255,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        full=True,
    )
    return {"comp_psnr": float(psnr), "comp_ssim": float(ssim.mean(axis=2)[region].mean())}


def compensation_means(scores: list[dict[str, float | None]]) -> dict[str, float | None]:
    """Means over samples of ``comp_psnr`` and ``comp_ssim`` (samples with an empty region skipped)."""
    out = {}
    for key in ("comp_psnr", "comp_ssim"):
        values = [s[key] for s in scores if s[key] is not None]
        out[key] = float(np.mean(values)) if values else None
    return out
