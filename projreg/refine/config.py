"""The geometric refinement's settings (:class:`RefineConfig`, the fast path's :data:`FAST_REFINE`) and
what one refinement reports about itself (:class:`RefineInfo`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import ProjregError

MIN_SIDE = 32  # below this DIS has no pyramid to work with: the flow is returned unchanged


@dataclass(frozen=True)
class RefineConfig:
    """Parameters of :class:`GeometricRefiner` (defaults chosen on the validation split, docs/model.md).

    ``grid``: B-spline control points (x, y); ``ransac_px``/``refit_px``: inlier thresholds of the first
    and the refitted homography; ``fit_points``: about how many grid correspondences the fits use;
    ``robust_px``: Cauchy scale of the spline's reweighting; ``ridge``: Tikhonov weight that keeps
    control points without texture under them at zero residual; ``ncc_sigma``: Gaussian window of the
    selection score (always on normalised images); ``contrast_sigma``: Gaussian window of the local
    contrast normalisation (0: none); ``plain_pass``: also try both hypotheses on the images without
    normalisation (four candidates instead of two); ``identity_pass``: also start from the identity
    (for pairs where the network is lost; without it, only when the network's flow has no homography);
    ``sift_pass``: also start from a SIFT + RANSAC homography of the pair (``baselines.SiftRansac``),
    when it finds one (for pairs where the network's hypothesis is wrong and the images' features
    still match: on the issue-14 test split it turned one pair's 28 px into 2.4 px); ``detail_grid``:
    the fine P-spline added to the coarse one where cross-validation says the residual carries finer
    surface detail (:func:`fit_detail`, penalty weights ``detail_bends``; None: the coarse spline
    only); ``periodic_peak`` and ``coarse_peak``: pixels where the projected image repeats itself
    (:func:`repeating`: its 64 px window scores at least ``periodic_peak``, a 128 or 256 px window at
    least ``coarse_peak``) are not claimed, whatever the checks say (``periodic_peak`` 1: no test);
    ``albedo_window``: the median window (odd, px) of the wall's reflectance estimate
    (:func:`divide_albedo`) under the albedo candidates' residual and in what the selection and the
    checks compare (0: no albedo candidates, and the checks see the normalised captured image as it
    is); ``max_side``: refine the pair shrunk to this longer side and bring the flow and the
    confidence back to its own grid (None: at its own size; the pixel parameters are then in the
    shrunk pair's pixels); ``plane_margin``: the best-scoring homography alone (SIFT's, or one
    refitted from a hypothesis before its residual is added) wins the selection when its score is
    within this margin of the best candidate's (:meth:`GeometricRefiner.select`); ``plane_agree_px``:
    a refitted homography competes only where it stays within this distance of its candidate (the
    homography plus the residual) on 90 % of the textured pixels (:func:`plane_agrees`);
    ``grow_below``: when the answer claims less than this share of the frame, the homography of its
    claimed pixels starts one more hypothesis (``"grown"``), which competes with the rest
    (:meth:`GeometricRefiner.grown`; 0: never); ``bridge_px``: a registered answer also claims a wide flat
    gap between verified texture (:func:`projreg.refine.confidence.gap_confidence`) where it stays within this
    distance of the homography of its own claimed pixels (:meth:`GeometricRefiner.bridged`; 0: never).
    """

    grid: tuple[int, int] = (6, 5)
    ransac_px: float = 2.0
    refit_px: float = 1.0
    fit_points: int = 12288
    robust_px: float = 1.0
    ridge: float = 1e-3
    irls_iterations: int = 3
    ncc_sigma: float = 7.0
    contrast_sigma: float = 8.0
    plain_pass: bool = True
    identity_pass: bool = True
    sift_pass: bool = True
    texture_floor: float = 256.0
    min_evidence: float = 0.01
    max_area_ratio: float = 6.0
    min_hull: float = 0.02
    free_px: float = 16.0
    support_margin: float = 0.1
    confidence_radius: float = 0.03
    rival_margin: float = 0.05
    detail_grid: tuple[int, int] | None = (14, 11)
    detail_bends: tuple[float, ...] = (0.3, 3.0, 30.0)
    periodic_peak: float = 0.85
    coarse_peak: float = 0.93
    albedo_window: int = 31
    max_side: int | None = None
    plane_margin: float = 0.005
    plane_agree_px: float = 2.0
    grow_below: float = 0.8
    bridge_px: float = 1.0

    def __post_init__(self) -> None:
        if min(self.grid) < 4:
            raise ProjregError(f"refine grid must have at least 4 x 4 control points, got {self.grid}")
        for name in ("ransac_px", "refit_px", "robust_px", "ncc_sigma"):
            if not getattr(self, name) > 0:
                raise ProjregError(f"refine {name} must be > 0, got {getattr(self, name)}")
        if self.max_side is not None and self.max_side < MIN_SIDE:
            raise ProjregError(f"refine max_side must be >= {MIN_SIDE}, got {self.max_side}")
        if self.albedo_window and (self.albedo_window < 3 or self.albedo_window % 2 == 0):
            raise ProjregError(f"refine albedo_window must be 0 (off) or an odd number >= 3, got {self.albedo_window}")
        if not 0 <= self.grow_below <= 1:
            raise ProjregError(f"refine grow_below must be in [0, 1] (0: never), got {self.grow_below}")
        for name in ("plane_margin", "plane_agree_px", "bridge_px"):
            if not getattr(self, name) >= 0:
                raise ProjregError(f"refine {name} must be >= 0, got {getattr(self, name)}")
        if not self.contrast_sigma >= 0:
            raise ProjregError(f"refine contrast_sigma must be >= 0 (0: no normalisation), got {self.contrast_sigma}")


# ``predict --fast``: the network's hypothesis on normalised images only (one candidate and its
# homography alone instead of eight and their homographies), without the detail level, the periodicity
# test, the albedo images and the bridge (7 ms more than its 44 ms of refinement per pair, for 0.3
# points of claims on validation), on the pair shrunk to 256 px with the pixel parameters halved
# (windows, thresholds, fit points for a 384 x 512 pair; its contrast window is 8 px, as measured:
# docs/history/2026-11-log.md, "Inference latency")
FAST_REFINE = RefineConfig(
    plain_pass=False,
    identity_pass=False,
    sift_pass=False,
    max_side=256,
    contrast_sigma=8.0,
    ncc_sigma=3.5,
    ransac_px=1.0,
    refit_px=0.5,
    robust_px=0.5,
    free_px=8.0,
    fit_points=3072,
    detail_grid=None,
    periodic_peak=1.0,
    albedo_window=0,
    bridge_px=0.0,
)


@dataclass(frozen=True)
class RefineInfo:
    """What :meth:`GeometricRefiner.refine` chose: ``hypothesis`` ("network", "identity", "sift", "grown",
    "none" for a textureless pair or "skipped"), ``images`` ("normalised", "plain" or "albedo": the gray images the
    residual was measured on; "homography": a homography unrefined, SIFT's or, for a pair nothing verifies,
    the one fitted to the network's flow), the selection score of every candidate tried, keyed
    ``"HYPOTHESIS/IMAGES"`` (texture-weighted mean local NCC, in [-1, 1]), the per-pixel ``confidence``
    (float32 ``(H, W)`` in [0, 1]) and ``evidence``, the share of the frame where the projected image has
    texture."""

    hypothesis: str
    images: str
    scores: dict[str, float]
    confidence: np.ndarray
    evidence: float
