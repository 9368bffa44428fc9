"""Geometric refinement of a network flow: projective fit, photometric residual, smooth surface model.

A projector-camera map is a homography (a plane seen by two pinhole devices) bent by lens distortion
and by the shape of the surface, both smooth over the frame. The network's flow finds that map
globally, through occlusions and large displacements, but only to a few pixels (its 1/8 matching and
its short training). This stage keeps what the network is good at and takes the precision from the
images:

0. **Local contrast normalisation** of both gray images (Gaussian window): blending, daylight and
   transparency change contrast differently across the frame, and DIS assumes it constant.
1. **Projective fit**: a homography fitted to the network's flow (MAGSAC++ on a grid of its
   correspondences). A second hypothesis, the identity, covers pairs where the network is lost.
2. **Photometric residual**: the captured image is warped into the projector frame by the current
   model, and DIS optical flow (mean-normalised patches) measures the remaining small residual;
   the homography is refitted once to ``model + residual`` and the residual measured again.
3. **Smooth surface model**: the residual is fitted by a tensor-product cubic B-spline (``grid``
   control points), weighted by the projected image's texture and made robust by iteratively
   reweighted least squares (Cauchy weights), so DIS's noise in flat or washed-out regions is
   averaged away instead of copied.
4. **Selection**: steps 1-3 run from both hypotheses, on the normalised and on the plain gray
   images (normalisation helps under blending and transparency, hurts some large, well-lit
   motions); each of the four flows is scored by the median local normalised cross-correlation
   (Gaussian window) between the normalised projected image and the normalised captured image
   warped back by it; the best score wins (ties: the first tried, the network's on normalised images).

The spline cannot follow a fold or an occlusion edge sharper than its control spacing (a third of the
frame's width); docs/model.md gives the measured effect of each step.

Convention: flows are float32 ``(H, W, 2)``, forward, projected -> captured, pixels:
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from . import ProjregError
from .baselines import homography_flow, proper_homography, to_gray
from .confidence import Prediction

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
    normalisation (four candidates instead of two).
    """

    grid: tuple[int, int] = (6, 5)
    ransac_px: float = 2.0
    refit_px: float = 1.0
    fit_points: int = 12288
    robust_px: float = 1.0
    ridge: float = 1e-3
    irls_iterations: int = 3
    ncc_sigma: float = 7.0
    contrast_sigma: float = 16.0
    plain_pass: bool = True

    def __post_init__(self) -> None:
        if min(self.grid) < 4:
            raise ProjregError(f"refine grid must have at least 4 x 4 control points, got {self.grid}")
        for name in ("ransac_px", "refit_px", "robust_px", "ncc_sigma"):
            if not getattr(self, name) > 0:
                raise ProjregError(f"refine {name} must be > 0, got {getattr(self, name)}")
        if not self.contrast_sigma >= 0:
            raise ProjregError(f"refine contrast_sigma must be >= 0 (0: no normalisation), got {self.contrast_sigma}")


@dataclass(frozen=True)
class RefineInfo:
    """What :meth:`GeometricRefiner.refine` chose: ``hypothesis`` ("network", "identity" or "skipped"),
    ``images`` ("normalised" or "plain": the gray images the residual was measured on), and the
    selection score of every candidate tried, keyed ``"HYPOTHESIS/IMAGES"`` (median local NCC, in
    [-1, 1])."""

    hypothesis: str
    images: str
    scores: dict[str, float]


class GeometricRefiner:
    """Refines network flows (module docstring); holds one DIS instance, so one refiner per thread."""

    def __init__(self, config: RefineConfig | None = None) -> None:
        self.config = config or RefineConfig()
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOpticalFlow_PRESET_MEDIUM)

    def refine(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, RefineInfo]:
        """The refined flow of one pair and which hypothesis produced it.

        Args:
            projected, captured: uint8 RGB ``(H, W, 3)`` of one size.
            flow: the network's flow for the pair, float ``(H, W, 2)``.

        Returns:
            float32 ``(H, W, 2)`` forward flow, and the :class:`RefineInfo`. Pairs with a side under
            ``MIN_SIDE`` come back unchanged (``hypothesis="skipped"``).
        """
        h, w = projected.shape[:2]
        if projected.shape != captured.shape or projected.ndim != 3 or flow.shape != (h, w, 2):
            raise ProjregError(f"refine needs projected, captured (H, W, 3) and flow (H, W, 2) of one size, got "
                               f"{projected.shape}, {captured.shape}, {flow.shape}")  # fmt: skip
        if min(h, w) < MIN_SIDE:
            return np.asarray(flow, np.float32), RefineInfo("skipped", "", {})
        cfg = self.config
        plain = (to_gray(projected), to_gray(captured))
        normalised = tuple(normalize_contrast(g, cfg.contrast_sigma) for g in plain)
        images = {"normalised": normalised}
        if cfg.plain_pass and cfg.contrast_sigma > 0:
            images["plain"] = plain
        step = fit_step(h, w, cfg.fit_points)
        hypotheses = {"network": fit_homography(flow, step, cfg.ransac_px), "identity": np.eye(3)}
        best, scores = None, {}
        for kind, (gray0, gray1) in images.items():
            weight = texture_weight(gray0)
            for name, H in hypotheses.items():
                if H is None:
                    continue
                cand = self.hypothesis(gray0, gray1, H, weight, step)[2]
                key = f"{name}/{kind}"
                scores[key] = alignment_score(*normalised, cand, cfg.ncc_sigma)
                if best is None or scores[key] > scores[best[0]]:
                    best = (key, cand)
        assert best is not None  # the identity always exists
        name, kind = best[0].split("/")
        return best[1], RefineInfo(name, kind, scores)

    def predict(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> Prediction:
        """:meth:`refine` as a :class:`~projreg.confidence.Prediction`."""
        return Prediction(self.refine(projected, captured, flow)[0])

    def hypothesis(
        self, gray0: np.ndarray, gray1: np.ndarray, H: np.ndarray, weight: np.ndarray, step: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Steps 2-3 from one starting homography, on one pair of gray images (normalised or plain).

        Returns:
            ``(base, residual, flow)``, float32 ``(H, W, 2)`` each: the refitted homography's flow, the
            DIS residual measured on it, and the refined flow ``compose(base, spline(residual))``.
        """
        cfg = self.config
        h, w = gray0.shape
        base = homography_flow(H, h, w)  # [H, W, 2]
        full = compose(base, self._residual(gray0, gray1, base))
        H2 = fit_homography(full, step, cfg.refit_px)
        if H2 is not None:
            base = homography_flow(H2, h, w)
        residual = self._residual(gray0, gray1, base)  # [H, W, 2], in the projector frame
        smooth = fit_bspline(residual, weight, cfg.grid, step, cfg.robust_px, cfg.ridge, cfg.irls_iterations)
        return base, residual, compose(base, smooth)

    def _residual(self, gray0: np.ndarray, gray1: np.ndarray, base: np.ndarray) -> np.ndarray:
        """DIS flow from the projected image to the captured image warped back by ``base``."""
        return self._dis.calc(gray0, warp_back(gray1, base), None)


def normalize_contrast(gray: np.ndarray, sigma: float) -> np.ndarray:
    """Local contrast normalisation: ``(g - mean) / std`` over a Gaussian window, as uint8 ``128 + 40 z``.

    The standard deviation is floored at 2 grey levels, so flat regions stay flat instead of turning
    their quantisation noise into texture. ``sigma`` 0 returns ``gray`` unchanged.
    """
    if sigma == 0:
        return gray
    g = gray.astype(np.float32)
    mean = cv2.GaussianBlur(g, (0, 0), sigma)
    var = cv2.GaussianBlur(g * g, (0, 0), sigma) - mean * mean
    z = (g - mean) / np.sqrt(np.maximum(var, 4.0))
    return np.clip(128 + 40 * z, 0, 255).astype(np.uint8)


def fit_step(h: int, w: int, points: int) -> int:
    """Grid step (>= 1 px) that leaves about ``points`` correspondences on an ``h x w`` frame."""
    return max(1, math.ceil(math.sqrt(h * w / points)))


def fit_homography(flow: np.ndarray, step: int, threshold: float) -> np.ndarray | None:
    """Robust homography (projected -> captured pixels) of a flow's correspondences on a ``step`` grid.

    MAGSAC++ with ``threshold`` px, OpenCV's RNG seeded first so the result is reproducible. None when
    no model is found, or when it sends part of the frame through infinity (``proper_homography``).
    """
    h, w = flow.shape[:2]
    y, x = np.mgrid[0:h:step, 0:w:step].astype(np.float32)  # [h', w'] each
    src = np.stack([x, y], axis=-1).reshape(-1, 2)  # [N, 2]
    dst = src + flow[::step, ::step].reshape(-1, 2)
    keep = np.isfinite(dst).all(axis=1)
    if keep.sum() < 8:
        return None
    cv2.setRNGSeed(0)
    H, _ = cv2.findHomography(src[keep], dst[keep], cv2.USAC_MAGSAC, threshold, maxIters=2000, confidence=0.999)
    return H if H is not None and proper_homography(H, h, w) else None


@lru_cache(maxsize=4)
def pixel_maps(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel x and y coordinates of an ``h x w`` frame, float32 ``(h, w)`` each; cached, read-only."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    x.flags.writeable = y.flags.writeable = False
    return x, y


def warp_back(gray1: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """The captured image seen in the projector frame: ``out[p] = gray1[p + flow(p)]`` (bilinear)."""
    x, y = pixel_maps(*flow.shape[:2])
    return cv2.remap(gray1, x + flow[..., 0], y + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def compose(base: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """``p -> q = p + r(p) -> q + base(q)``: a residual measured on an image warped back by ``base``.

    If ``warp_back(gray1, base)`` matches the projected image under ``residual``, the pair matches
    under the returned flow: ``r(p) + base(p + r(p))``.
    """
    x, y = pixel_maps(*base.shape[:2])
    moved = cv2.remap(base, x + residual[..., 0], y + residual[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    return (residual + moved).astype(np.float32)


def texture_weight(gray: np.ndarray, sigma: float = 3.0) -> np.ndarray:
    """Per-pixel weight in [0, 1]: local gradient energy relative to the frame's median, capped at 1."""
    g = gray.astype(np.float32)
    energy = cv2.GaussianBlur(cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2,
                              (0, 0), sigma)  # fmt: skip
    return np.minimum(energy / (float(np.median(energy)) + 1e-3), 1.0)


def bspline_basis(n: int, k: int) -> np.ndarray:
    """Uniform cubic B-spline basis ``(n, k)``: ``k`` control points spanning samples ``0 .. n-1``.

    The first and last control points lie one knot outside the frame, so the basis sums to 1 at every
    sample (a constant residual is represented exactly).

    Example:
        >>> bool(np.allclose(bspline_basis(50, 6).sum(axis=1), 1.0))
        True
    """
    t = np.arange(n) / max(n - 1, 1) * (k - 3)  # [n], sample positions in knot units
    d = np.abs(t[:, None] - (np.arange(k)[None, :] - 1))  # [n, k]
    return np.where(d < 1, 2 / 3 - d**2 + d**3 / 2, np.where(d < 2, (2 - d) ** 3 / 6, 0.0))


def fit_bspline(
    field: np.ndarray,
    weight: np.ndarray,
    grid: tuple[int, int],
    step: int = 4,
    robust: float = 1.0,
    ridge: float = 1e-3,
    iterations: int = 3,
) -> np.ndarray:
    """Robust weighted least-squares cubic B-spline fit of a 2-channel field.

    Args:
        field: float ``(H, W, 2)``; fitted on every ``step``-th pixel.
        weight: float ``(H, W)`` >= 0, the confidence of each pixel.
        grid: control points ``(kx, ky)``.
        robust: Cauchy scale (field units) of the reweighting after the first solve.
        ridge: Tikhonov weight towards zero on the control values.
        iterations: weighted solves (the first unweighted by residuals).

    Returns:
        float32 ``(H, W, 2)``, the spline evaluated at every pixel.
    """
    h, w = field.shape[:2]
    kx, ky = grid
    By, Bx = bspline_basis(h, ky), bspline_basis(w, kx)  # [H, ky], [W, kx]
    A = np.einsum("yi,xj->yxij", By[::step], Bx[::step]).reshape(-1, ky * kx)  # [N, K]
    f = field[::step, ::step].reshape(-1, 2).astype(np.float64)  # [N, 2]
    w0 = weight[::step, ::step].reshape(-1).astype(np.float64)  # [N]
    ok = np.isfinite(f).all(axis=1)
    f, w0 = np.where(ok[:, None], f, 0.0), np.where(ok, w0, 0.0)
    fit = np.zeros_like(f)
    for it in range(iterations):
        wi = w0 if it == 0 else w0 / (1 + (np.linalg.norm(f - fit, axis=1) / robust) ** 2)
        c = np.linalg.solve(A.T @ (A * wi[:, None]) + ridge * np.eye(A.shape[1]), A.T @ (f * wi[:, None]))  # [K, 2]
        fit = A @ c
    c = c.reshape(ky, kx, 2)
    return np.stack([By @ c[..., i] @ Bx.T for i in range(2)], axis=-1).astype(np.float32)


def alignment_score(gray0: np.ndarray, gray1: np.ndarray, flow: np.ndarray, sigma: float = 7.0) -> float:
    """Median over the frame of the local normalised cross-correlation of ``gray0`` and ``gray1``
    warped back by ``flow`` (Gaussian window ``sigma``): 1 is a perfect match up to local gain and
    offset, about 0 no match."""
    a = gray0.astype(np.float32)
    b = warp_back(gray1, flow).astype(np.float32)

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, (0, 0), sigma)

    ma, mb = blur(a), blur(b)
    cov = blur(a * b) - ma * mb
    var = np.maximum((blur(a * a) - ma * ma) * (blur(b * b) - mb * mb), 1e-2)
    return float(np.median(cov / np.sqrt(var)))
