"""Geometric refinement of a network flow: projective fit, photometric residual, smooth surface model.

A projector-camera map is a homography (a plane seen by two pinhole devices) bent by lens distortion
and by the shape of the surface, both smooth over the frame. The network's flow finds that map
globally, through occlusions and large displacements, but only to a few pixels (its 1/8 matching and
its short training). This stage keeps what the network is good at and takes the precision from the
images:

0. **Local contrast normalisation** of both gray images (Gaussian window): blending, daylight and
   transparency change contrast differently across the frame, and DIS assumes it constant.
1. **Projective fit**: a homography fitted to the network's flow (MAGSAC++ on a grid of its
   correspondences). A second hypothesis, the identity, covers pairs where the network is lost; a
   third, a SIFT + RANSAC homography of the pair (when SIFT finds one), pairs where the network's
   hypothesis is wrong but the images' features still match.
2. **Photometric residual**: the captured image is warped into the projector frame by the current
   model, and DIS optical flow (mean-normalised patches) measures the remaining small residual;
   the homography is refitted once to ``model + residual`` and the residual measured again.
3. **Smooth surface model**: the residual is fitted by a tensor-product cubic B-spline (``grid``
   control points), weighted by the projected image's texture and made robust by iteratively
   reweighted least squares (Cauchy weights), so DIS's noise in flat or washed-out regions is
   averaged away instead of copied. What it leaves is fitted once more by a finer P-spline
   (``detail_grid``) when block cross-validation says that predicts held-out pixels better: a sheet
   bent with a period shorter than the coarse knots, not DIS's noise.
4. **Selection**: steps 1-3 run from every hypothesis, on the normalised and on the plain gray
   images (normalisation helps under blending and transparency, hurts some large, well-lit
   motions), and from the network's and SIFT's on the *albedo* images: the plain ones with the
   wall's reflectance (painted stripes, bricks) divided out of the warped captured image before
   both are normalised (:func:`divide_albedo`). Each flow is scored by the texture-weighted mean
   local normalised cross-correlation (Gaussian window) between the normalised projected image and
   the captured image warped back by it, the wall's reflectance divided out the same way
   (:meth:`GeometricRefiner.seen`); the best score wins (ties: the first tried, the network's on
   normalised images).
5. **Growth**: when the winner verifies less than ``grow_below`` of the frame, the homography of its
   claimed pixels starts steps 2-3 once more (``"grown"``), selected with the rest: the verified
   part's plane is a better start for the part the first answer missed.

The spline cannot follow a fold or an occlusion edge sharper than its control spacing (a third of the
frame's width); docs/model.md gives the measured effect of each step.

Convention: flows are float32 ``(H, W, 2)``, forward, projected -> captured, pixels:
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from threadpoolctl import ThreadpoolController

from . import ProjregError
from .baselines import SiftRansac, homography_flow, proper_homography, to_gray
from .confidence import CONFIDENT, Prediction, gap_confidence, pixel_confidence, ramp
from .frames import resize_flow, shrink

MIN_SIDE = 32  # below this DIS has no pyramid to work with: the flow is returned unchanged
_BLAS = ThreadpoolController()


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
    gap between verified texture (:func:`projreg.confidence.gap_confidence`) where it stays within this
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
# (windows, thresholds, fit points for a 384 x 512 pair; its contrast window, 8 px, is half the
# full-size default before session 9, as measured);
# docs/history/2026-11-log.md ("Inference latency")
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


class GeometricRefiner:
    """Refines network flows (module docstring); holds one DIS instance, so one refiner per thread."""

    def __init__(self, config: RefineConfig | None = None) -> None:
        self.config = config or RefineConfig()
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOpticalFlow_PRESET_MEDIUM)
        self._sift = SiftRansac() if self.config.sift_pass else None

    def refine(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, RefineInfo]:
        """The refined flow of one pair and which hypothesis produced it (:meth:`predict` without the
        confidence)."""
        pred, info = self.predict_info(projected, captured, flow)
        return pred.flow, info

    def predict(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> Prediction:
        """The refined flow with the pixels it claims (confidence >= ``CONFIDENT``) and whether the
        pair registered at all; see :meth:`predict_info`."""
        return self.predict_info(projected, captured, flow)[0]

    def predict_info(
        self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray, identity: bool = True
    ) -> tuple[Prediction, RefineInfo]:
        """Refine one pair: flow, per-pixel confidence, registered or not, and what was chosen.

        Args:
            projected, captured: uint8 RGB ``(H, W, 3)`` of one size.
            flow: the network's flow for the pair, float ``(H, W, 2)`` (or, tracking, the previous
                frame's: :mod:`projreg.track`).
            identity: also try the identity and the SIFT hypotheses (tracking leaves them out while
                ``flow`` has a homography fit; its ``hypothesis`` is then "network" unless that fit
                failed); the config's ``identity_pass`` / ``sift_pass`` off leave them out always
                (``FAST_REFINE``).

        Returns:
            The :class:`~projreg.confidence.Prediction` (float32 ``(H, W, 2)`` forward flow, the pixels
            whose confidence is at least ``CONFIDENT``, ``registered``) and the :class:`RefineInfo`
            (its ``confidence`` is the per-pixel map). A pair whose projected image has texture on
            less than ``min_evidence`` of the frame is not registered: the flow is zero (the
            projection is left where it is) and nothing is claimed. Pairs with a side under
            ``MIN_SIDE`` come back unchanged and unclaimed (``hypothesis="skipped"``).
        """
        h, w = projected.shape[:2]
        if projected.shape != captured.shape or projected.ndim != 3 or flow.shape != (h, w, 2):
            raise ProjregError(
                f"refine needs projected, captured (H, W, 3) and flow (H, W, 2) of one size, got "
                f"{projected.shape}, {captured.shape}, {flow.shape}"
            )
        flow = np.asarray(flow, np.float32)
        if self.config.max_side is not None and max(h, w) > self.config.max_side:
            return self._predict_shrunk(projected, captured, flow, identity)
        none = np.zeros((h, w), np.float32)
        if min(h, w) < MIN_SIDE:
            return Prediction(flow, none > 0, False, "too small"), RefineInfo("skipped", "", {}, none, 0.0)
        cfg = self.config
        plain, normalised, evidence = self.views(projected, captured)
        share = float((evidence >= 0.5).mean())
        if share < cfg.min_evidence:
            why = f"textureless: {100 * share:.1f}% of the projected image carries texture"
            return Prediction(np.zeros_like(flow), none > 0, False, why), RefineInfo("none", "", {}, none, share)
        images = {"normalised": normalised}
        if cfg.plain_pass and cfg.contrast_sigma > 0:
            images["plain"] = plain
        if cfg.albedo_window:
            images["albedo"] = plain  # the residual divides the wall's reflectance out (divide_albedo)
        step = fit_step(h, w, cfg.fit_points)
        textured = evidence >= 0.5
        support = near(textured, cfg.support_margin * max(h, w))
        hypotheses = self._hypotheses(projected, captured, flow, step, identity)
        memo: dict[str, np.ndarray] = {}  # each candidate's check maps: scored once, the confidence runs up to 3 times
        cands, scores = self._candidates(images, hypotheses, plain, evidence, step, textured, support, memo)
        best = self.select(scores)
        # a repeating pattern: a flow off by one period passes every check (computed once per pair)
        repeats = repeating(normalised[0], cfg.periodic_peak, cfg.coarse_peak) if cfg.periodic_peak < 1 else None
        conf = self.confidence(normalised, cands, scores, best, evidence, repeats, plain, memo)
        grown = self.grown(cands[best], conf >= CONFIDENT, step)
        if grown:  # the verified region's plane, refined again, may verify more of the frame
            more, more_scores = self._candidates(images, grown, plain, evidence, step, textured, support, memo)
            cands.update(more)
            scores.update(more_scores)
            best = self.select(scores)
            conf = self.confidence(normalised, cands, scores, best, evidence, repeats, plain, memo)
        net = [k for k in scores if k.startswith("network/")]
        if (conf >= CONFIDENT).mean() < cfg.min_evidence and net and best not in net:
            # nothing verified (e.g. content washed out by daylight): the scores carry no evidence,
            # so the answer stays with the network's hypothesis rather than the identity's
            best = max(net, key=lambda k: scores[k])
            conf = self.confidence(normalised, cands, scores, best, evidence, repeats, plain, memo)
        claimed = conf >= CONFIDENT
        why = "" if claimed.mean() >= cfg.min_evidence else unverified(claimed, repeats, textured)
        if not why and cfg.bridge_px > 0:  # the answer's flat gaps, where two models of them agree
            radius = cfg.confidence_radius * max(h, w)
            gap = gap_confidence(evidence, *self.checks(normalised, cands, scores, best, plain, memo), radius)
            conf = self.bridged(conf, cands[best], gap if repeats is None else np.where(repeats, 0.0, gap))
            claimed = conf >= CONFIDENT
        if why and hypotheses["network"][0] is not None:
            # nothing verified: the residuals fitted on images that carry no evidence only add noise, and the
            # homography of the network's own flow is the smoothest statement of its hypothesis (docs/model.md)
            best = "network/homography"
            cands[best] = homography_flow(hypotheses["network"][0], h, w)
            scores[best] = weighted_ncc(
                normalised[0], self.seen(cands[best], normalised, plain), cfg.ncc_sigma, evidence
            )
        name, kind = best.split("/")
        # a pair reported as not registered claims nothing: a few stray pixels passing the checks are not
        # a registration the user can rely on (the confidence map in RefineInfo keeps them)
        pred = Prediction(cands[best], claimed if not why else np.zeros_like(claimed), not why, why)
        return pred, RefineInfo(name, kind, scores, conf, share)

    def select(self, scores: dict[str, float]) -> str:
        """The winning candidate: the highest score (ties: the first tried), unless a homography alone (a key
        ending in "homography") scores within ``plane_margin`` of it. Where a plane explains the images as
        well as the plane plus its fitted residual, the residual adds only DIS's noise, and sub-pixel
        differences move the score by thousandths (docs/model.md, "selection")."""
        order = {key: i for i, key in enumerate(scores)}

        def rank(key: str) -> tuple[float, int]:
            return scores[key], -order[key]

        best = max(scores, key=rank)
        plane = max((k for k in scores if k.endswith("homography")), key=rank, default=None)
        return plane if plane is not None and scores[plane] >= scores[best] - self.config.plane_margin else best

    def _hypotheses(
        self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray, step: int, identity: bool
    ) -> dict[str, tuple[np.ndarray | None, np.ndarray]]:
        """The starts of the refinement, by name: ``(homography or None, flow)`` for the network's flow,
        the identity and SIFT's homography (``identity``, and the config's passes, decide the last two)."""
        cfg, (h, w) = self.config, flow.shape[:2]
        # the network's own flow is fitted everywhere: it carries the network's hypothesis into flat
        # regions too, and the refit in the candidates keeps to the textured pixels
        start = fit_homography(flow, step, cfg.ransac_px, None, math.inf, cfg.min_hull)
        fit = start if start is not None and area_ratio(start[0], h, w) <= cfg.max_area_ratio else None
        # the network's start is never dropped: a homography too bent to trust as an answer (strong lens
        # distortion) still starts a refinement that verifies what it finds; an affine fit when none is found
        start = start or fit_affine(flow, step, cfg.ransac_px, cfg.min_hull)
        hypotheses = {"network": (None if start is None else start[0], flow)}
        if (identity and cfg.identity_pass) or fit is None:
            hypotheses["identity"] = (np.eye(3), np.zeros_like(flow))
        if identity and self._sift is not None:
            hypotheses.update(self._sift_hypothesis(projected, captured, step))
        return hypotheses

    def grown(self, flow: np.ndarray, claimed: np.ndarray, step: int) -> dict:
        """``{"grown": (H, flow)}``: the homography of ``flow`` on its ``claimed`` pixels (bool ``(H, W)``)
        as one more hypothesis, when the claim covers at least ``min_evidence`` and less than ``grow_below``
        of the frame and that homography fits (well conditioned, inliers' hull at least ``min_hull``);
        else ``{}``.

        A candidate often verifies one part of the frame and misses the rest: its residual converged
        where its start was close and not elsewhere, or the start (the network's flow) was wrong there.
        The plane of the verified part is a better start for the rest on a smooth surface; refined and
        checked like every other, it wins only where it explains the images better. On the validation
        split's one catastrophe of the fast path (network 27 px off, its candidate 44 px) it gave 2.0 px;
        docs/model.md, "Grown from the verified region"."""
        cfg = self.config
        share = float(claimed.mean())
        if not cfg.min_evidence <= share < cfg.grow_below:
            return {}
        h, w = flow.shape[:2]
        fit = fit_homography(flow, step, cfg.ransac_px, claimed, cfg.max_area_ratio, cfg.min_hull)
        return {} if fit is None else {"grown": (fit[0], homography_flow(fit[0], h, w))}

    def _candidates(
        self,
        images: dict[str, tuple[np.ndarray, np.ndarray]],
        hypotheses: dict[str, tuple[np.ndarray | None, np.ndarray]],
        plain: tuple[np.ndarray, np.ndarray],
        evidence: np.ndarray,
        step: int,
        textured: np.ndarray,
        support: np.ndarray,
        memo: dict[str, np.ndarray],
    ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Steps 2-4 from every hypothesis on every kind of images: the refined flows and their selection
        scores, keyed ``"HYPOTHESIS/IMAGES"`` in the order tried. The albedo images start from the
        network's and SIFT's homographies only: from the identity they changed nothing on the validation
        split and cost a fifth more time (docs/model.md, "Textured walls"). The homographies alone compete
        too: SIFT's (``"sift/homography"``) and each one refitted before its residual is added
        (``"HYPOTHESIS/IMAGES-homography"``), where it refitted and stays close to its candidate on the
        textured pixels (:func:`plane_agrees`); on a planar scene the residual adds only DIS's noise. ``memo``
        receives each candidate's local NCC map (key ``"ncc:KEY"``), which the score averages and the
        confidence reads again (:meth:`confidence`)."""
        cfg = self.config
        normalised = images["normalised"]
        cands, planes, scores = {}, {}, {}
        for kind, (gray0, gray1) in images.items():
            weight = texture_weight(gray0, 0.0 if kind == "normalised" else cfg.texture_floor)
            albedo = cfg.albedo_window if kind == "albedo" else 0
            for name, (H, prior) in hypotheses.items():
                if H is None or (albedo and name == "identity"):
                    continue
                key = f"{name}/{kind}"
                base, _, cands[key], refitted = self.hypothesis(
                    gray0, gray1, H, weight, step, textured, support, prior, albedo
                )
                plane = bound_outside(base, prior, support, cfg.free_px)
                if refitted and plane_agrees(plane, cands[key], textured, cfg.plane_agree_px):
                    planes[f"{key}-homography"] = plane
        if "sift" in hypotheses:  # SIFT's homography as it is, which no residual refines
            planes["sift/homography"] = homography_flow(hypotheses["sift"][0], *normalised[0].shape)
        cands.update(planes)
        for key in cands:  # the local NCC maps are the confidence's too (memo)
            scores[key] = weighted_mean(self.local(key, cands, normalised, plain, memo), evidence)
        return cands, scores

    def _predict_shrunk(
        self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray, identity: bool
    ) -> tuple[Prediction, RefineInfo]:
        """:meth:`predict_info` on the pair shrunk to ``max_side``; flow and confidence resized back
        (bilinear), the claimed pixels those whose resized confidence is at least ``CONFIDENT``."""
        side = self.config.max_side
        small0, small1 = shrink(projected, side), shrink(captured, side)
        pred, info = self.predict_info(small0, small1, resize_flow(flow, small0.shape), identity)
        h, w = projected.shape[:2]
        conf = cv2.resize(info.confidence, (w, h), interpolation=cv2.INTER_LINEAR)  # [H, W]
        pred = replace(pred, flow=resize_flow(pred.flow, projected.shape), claimed=conf >= CONFIDENT)
        return pred, replace(info, confidence=conf)

    def _sift_hypothesis(self, projected: np.ndarray, captured: np.ndarray, step: int) -> dict:
        """``{"sift": (H, flow)}`` when SIFT + RANSAC finds a proper homography of the pair, else ``{}``."""
        flow = self._sift.predict(projected, captured)
        if self._sift.last_status != "ok":
            return {}
        fit = fit_homography(flow, step, self.config.ransac_px, None, self.config.max_area_ratio, self.config.min_hull)
        return {} if fit is None else {"sift": (fit[0], flow)}

    def hypothesis(
        self,
        gray0: np.ndarray,
        gray1: np.ndarray,
        H: np.ndarray,
        weight: np.ndarray,
        step: int,
        textured: np.ndarray,
        support: np.ndarray,
        prior: np.ndarray,
        albedo: int = 0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """Steps 2-3 from one starting homography, on one pair of gray images (normalised or plain;
        plain with an ``albedo`` window: the residual divides the wall's reflectance out, :meth:`_residual`),
        with the guards: the refit uses ``textured`` pixels only and must be well conditioned, and
        outside ``support`` (farther than ``support_margin`` from any texture: no evidence) the
        answer stays within ``free_px`` of ``prior``, the hypothesis it started from (the network's
        flow, or zero for the identity).

        Returns:
            ``(base, residual, flow, refitted)``: float32 ``(H, W, 2)`` each, the refitted homography's flow
            (the start's where the refit found none: ``refitted`` False), the DIS residual measured on it,
            and the refined flow ``compose(base, spline(residual))`` (:meth:`surface`).
        """
        cfg = self.config
        h, w = gray0.shape
        base = homography_flow(H, h, w)  # [H, W, 2]
        full = compose(base, self._residual(gray0, gray1, base, albedo))
        fit = fit_homography(full, step, cfg.refit_px, textured, cfg.max_area_ratio, cfg.min_hull)
        if fit is not None:
            base = homography_flow(fit[0], h, w)
        residual = self._residual(gray0, gray1, base, albedo)  # [H, W, 2], in the projector frame
        return base, residual, self.surface(base, residual, weight, step, support, prior), fit is not None

    def surface(
        self,
        base: np.ndarray,
        residual: np.ndarray,
        weight: np.ndarray,
        step: int,
        support: np.ndarray,
        prior: np.ndarray,
    ) -> np.ndarray:
        """Step 3: ``base`` composed with the coarse spline of ``residual`` (and, with a ``detail_grid``,
        the cross-validated fine level, :func:`fit_detail`), held within ``free_px`` of ``prior`` outside
        ``support``."""
        cfg = self.config
        smooth = fit_bspline(residual, weight, cfg.grid, step, cfg.robust_px, cfg.ridge, cfg.irls_iterations)
        if cfg.detail_grid is not None:
            smooth = (
                smooth
                + fit_detail(residual - smooth, weight, cfg.detail_grid, cfg.detail_bends, step, cfg.robust_px)[0]
            )
        return bound_outside(compose(base, smooth), prior, support, cfg.free_px)

    def confidence(
        self,
        normalised: tuple[np.ndarray, np.ndarray],
        cands: dict[str, np.ndarray],
        scores: dict[str, float],
        best: str,
        evidence: np.ndarray,
        repeating: np.ndarray | None = None,
        plain: tuple[np.ndarray, np.ndarray] | None = None,
        memo: dict[str, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Per-pixel confidence in [0, 1] of candidate ``best`` (:func:`projreg.confidence.pixel_confidence`):
        texture, local NCC, forward-backward residual and agreement with the close runners-up; 0 where
        ``repeating`` (bool ``(H, W)``: the projected image repeats itself, :func:`periodicity`). ``memo``
        (a dict kept for one pair) holds each candidate's check maps, so a second call on the same
        candidates computes only what is new."""
        radius = self.config.confidence_radius * max(normalised[0].shape)
        conf = pixel_confidence(evidence, *self.checks(normalised, cands, scores, best, plain, memo), radius)
        return conf if repeating is None else np.where(repeating, 0.0, conf).astype(np.float32)

    def checks(
        self,
        normalised: tuple[np.ndarray, np.ndarray],
        cands: dict[str, np.ndarray],
        scores: dict[str, float],
        best: str,
        plain: tuple[np.ndarray, np.ndarray] | None = None,
        memo: dict[str, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate ``best``'s check maps, float32 ``(H, W)`` each: local NCC, forward-backward residual (px)
        and the rivals' spread (px, :meth:`ambiguity`); the first two kept in ``memo``."""
        memo = {} if memo is None else memo
        if f"residual:{best}" not in memo:
            memo[f"residual:{best}"] = self.round_trip(normalised[0], self.seen(cands[best], normalised, plain))
        ncc = self.local(best, cands, normalised, plain, memo)
        return ncc, memo[f"residual:{best}"], self.ambiguity(normalised, cands, scores, best, ncc, plain, memo)

    def bridged(self, conf: np.ndarray, flow: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """``conf`` raised to ``gap`` (the checks averaged across a wide flat gap,
        :func:`projreg.confidence.gap_confidence`) where ``flow`` stays within ``bridge_px`` of the homography
        fitted to it on its claimed pixels (``conf >= CONFIDENT``); ``conf`` itself when that fit fails.

        In a flat gap the answer is the surface model's interpolation; where the plane of the verified
        region says the same, two models of the gap agree and the gap is claimed. Where the surface bends
        away from that plane, or the answer is held to a guess (a region farther from texture than
        ``support_margin``), they part and the claim stays with the checks. On a development rendering of
        the real pictures: claimed 67.2 -> 69.7 %, worst claimed pair unchanged (docs/model.md)."""
        cfg, (h, w) = self.config, flow.shape[:2]
        claimed = conf >= CONFIDENT
        fit = fit_homography(
            flow, fit_step(h, w, cfg.fit_points), cfg.ransac_px, claimed, cfg.max_area_ratio, cfg.min_hull
        )
        if fit is None:
            return conf
        agree = np.linalg.norm(flow - homography_flow(fit[0], h, w), axis=-1) < cfg.bridge_px
        return np.where(agree, np.maximum(conf, gap), conf).astype(np.float32)

    def round_trip(self, gray0: np.ndarray, warped: np.ndarray) -> np.ndarray:
        """Forward-backward residual (px, ``(H, W)``) between the projected image and the captured one
        warped back by a flow: what DIS still finds to move, either way round; ~0 where the flow holds."""
        fwd = self._dis.calc(gray0, warped, None)
        bwd = self._dis.calc(warped, gray0, None)
        return np.maximum(np.linalg.norm(fwd, axis=-1), np.linalg.norm(compose(bwd, fwd), axis=-1))

    def local(
        self,
        key: str,
        cands: dict[str, np.ndarray],
        normalised: tuple[np.ndarray, np.ndarray],
        plain: tuple[np.ndarray, np.ndarray] | None,
        memo: dict[str, np.ndarray],
    ) -> np.ndarray:
        """Local NCC map of candidate ``key`` (:func:`local_ncc` of what :meth:`seen` shows), kept in ``memo``."""
        if f"ncc:{key}" not in memo:
            memo[f"ncc:{key}"] = local_ncc(
                normalised[0], self.seen(cands[key], normalised, plain), self.config.ncc_sigma
            )
        return memo[f"ncc:{key}"]

    def ambiguity(
        self,
        normalised: tuple[np.ndarray, np.ndarray],
        cands: dict[str, np.ndarray],
        scores: dict[str, float],
        best: str,
        ncc: np.ndarray,
        plain: tuple[np.ndarray, np.ndarray] | None = None,
        memo: dict[str, np.ndarray] | None = None,
    ) -> np.ndarray:
        """How far, per pixel, the rivals of candidate ``best`` that explain the images about as well lie from
        it (px, float32 ``(H, W)``; the confidence's ``spread``).

        A rival is a candidate scoring within ``rival_margin`` of the winner (a refitted plane is its
        candidate simplified, not another explanation: never a rival), and it counts at a pixel only
        where its own local NCC is within ``rival_margin`` of the winner's ``ncc`` there. Two answers
        that both explain a neighbourhood (a repeating pattern) leave it ambiguous; a rival that fails
        there (a candidate whose residual did not converge on that part of the frame) is just wrong
        there and took 2 points of claimed share from the development rig (docs/model.md). ``memo``: as
        in :meth:`confidence`."""
        cfg, flow = self.config, cands[best]
        memo = {} if memo is None else memo
        spread = np.zeros(flow.shape[:2], np.float32)
        for key, other in cands.items():
            if key == best or key.endswith("-homography") or scores[key] < scores[best] - cfg.rival_margin:
                continue
            explains = self.local(key, cands, normalised, plain, memo) >= ncc - cfg.rival_margin
            spread = np.maximum(spread, np.where(explains, np.linalg.norm(other - flow, axis=-1), 0.0))
        return spread

    def score(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> float:
        """The selection score of ``flow`` on a pair of uint8 RGB images, as :meth:`predict_info` scores its
        candidates (at the pair's own size): texture-weighted mean local NCC of what :meth:`seen` shows."""
        plain, normalised, evidence = self.views(projected, captured)
        return weighted_ncc(normalised[0], self.seen(flow, normalised, plain), self.config.ncc_sigma, evidence)

    def views(self, projected: np.ndarray, captured: np.ndarray) -> tuple[tuple, tuple, np.ndarray]:
        """The pair as the refinement reads it: the ``plain`` gray images, the ``normalised`` ones (local
        contrast normalisation) and the projected image's absolute texture (``evidence``, ``(H, W)`` in [0, 1])."""
        plain = (to_gray(projected), to_gray(captured))
        normalised = tuple(normalize_contrast(g, self.config.contrast_sigma) for g in plain)
        return plain, normalised, texture_weight(plain[0], self.config.texture_floor)

    def seen(
        self, flow: np.ndarray, normalised: tuple[np.ndarray, np.ndarray], plain: tuple[np.ndarray, np.ndarray] | None
    ) -> np.ndarray:
        """The captured image warped back into the projector frame by ``flow``, as the selection and the
        checks compare it with the projected one: normalised, and with an ``albedo_window`` (and the
        ``plain`` images given) the wall's reflectance divided out first (:func:`divide_albedo`; docs/model.md,
        "Textured walls")."""
        cfg = self.config
        if plain is None or not cfg.albedo_window:
            return warp_back(normalised[1], flow)
        warped = divide_albedo(plain[0], warp_back(plain[1], flow), cfg.albedo_window)
        return normalize_contrast(warped, cfg.contrast_sigma)

    def _residual(self, gray0: np.ndarray, gray1: np.ndarray, base: np.ndarray, albedo: int = 0) -> np.ndarray:
        """DIS flow from the projected image to the captured image warped back by ``base``; with an
        ``albedo`` window, ``gray0``/``gray1`` are the plain images and the warped one is divided by the
        wall's estimated reflectance (:func:`divide_albedo`) before both are normalised."""
        warped = warp_back(gray1, base)
        if not albedo:
            return self._dis.calc(gray0, warped, None)
        sigma = self.config.contrast_sigma
        corrected = divide_albedo(gray0, warped, albedo)
        return self._dis.calc(normalize_contrast(gray0, sigma), normalize_contrast(corrected, sigma), None)


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


def divide_albedo(gray0: np.ndarray, warped: np.ndarray, window: int) -> np.ndarray:
    """``warped`` (the captured gray image in the projector frame) divided by the wall's reflectance.

    A textured wall (paint, brick, plaster) multiplies the projected light; through a power-law camera
    response the captured image is still the projected one times a reflectance map that carries the
    wall's own edges, which contrast normalisation keeps and DIS follows. The reflectance is estimated
    as the median, over a ``window`` x ``window`` square, of ``log(warped + 8) - log(gray0 + 8)``: a
    wall's stripes or bricks wider than half the window survive the median, the texture-scale
    structure a small misalignment leaves in the ratio does not. Returns float32 ``(H, W)``.
    """
    ratio = np.log(warped.astype(np.float32) + 8.0) - np.log(gray0.astype(np.float32) + 8.0)
    coded = np.clip(np.round(128 + 40 * ratio), 0, 255).astype(np.uint8)  # OpenCV's large medians take uint8
    return warped / np.exp((cv2.medianBlur(coded, window).astype(np.float32) - 128) / 40)


def fit_step(h: int, w: int, points: int) -> int:
    """Grid step (>= 1 px) that leaves about ``points`` correspondences on an ``h x w`` frame."""
    return max(1, math.ceil(math.sqrt(h * w / points)))


Fit = tuple[np.ndarray, np.ndarray] | None  # (3 x 3 matrix, bool (H, W) hull of its inliers), or None


def fit_homography(
    flow: np.ndarray,
    step: int,
    threshold: float,
    mask: np.ndarray | None = None,
    max_area_ratio: float = math.inf,
    min_hull: float = 0.0,
) -> Fit:
    """Robust homography (projected -> captured pixels) of a flow's correspondences on a ``step`` grid.

    MAGSAC++ with ``threshold`` px, OpenCV's RNG seeded first so the result is reproducible, on the
    grid points where ``mask`` (bool ``(H, W)``, None: all) is true.

    Returns:
        ``(H, hull)``: the 3 x 3 matrix and the bool ``(H, W)`` convex hull of its inliers (the region
        the fit interpolates; outside it, it extrapolates). None when no model is found, when it
        sends part of the frame through infinity (``proper_homography``), when it is badly
        conditioned (its local area scale varies more than ``max_area_ratio`` times over the frame,
        or flips orientation: ``area_ratio``), or when the hull covers less than ``min_hull`` of it.
    """
    h, w = flow.shape[:2]
    src, dst = _grid_matches(flow, step, mask)
    if len(src) < 8:
        return None
    cv2.setRNGSeed(0)
    H, inl = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, threshold, maxIters=2000, confidence=0.999)
    if H is None or inl is None or inl.sum() < 8 or not proper_homography(H, h, w):
        return None
    if not area_ratio(H, h, w) <= max_area_ratio:
        return None
    return _with_hull(H, src[inl.ravel() > 0], h, w, min_hull)


def fit_affine(flow: np.ndarray, step: int, threshold: float, min_hull: float = 0.0) -> Fit:
    """:func:`fit_homography` with an affine model (returned as a 3 x 3 matrix): the start from a flow
    whose homography is refused as badly conditioned, e.g. under strong lens distortion, where the
    best homography over the frame bends too much. An affine map's area scale is the same everywhere,
    so it cannot be ill conditioned that way; it only starts a refinement that measures the rest."""
    h, w = flow.shape[:2]
    src, dst = _grid_matches(flow, step, None)
    if len(src) < 8:
        return None
    cv2.setRNGSeed(0)
    A, inl = cv2.estimateAffine2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=threshold, maxIters=2000)
    if A is None or inl is None or inl.sum() < 8 or np.linalg.det(A[:, :2]) <= 0:
        return None
    return _with_hull(np.vstack([A, [0.0, 0.0, 1.0]]), src[inl.ravel() > 0], h, w, min_hull)


def _grid_matches(flow: np.ndarray, step: int, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(src, dst)`` float32 ``[N, 2]``: the ``step`` grid's projected pixels where the flow is finite
    (and ``mask``, when given, is true) and where the flow sends them."""
    h, w = flow.shape[:2]
    y, x = np.mgrid[0:h:step, 0:w:step].astype(np.float32)  # [h', w'] each
    src = np.stack([x, y], axis=-1).reshape(-1, 2)  # [N, 2]
    dst = src + flow[::step, ::step].reshape(-1, 2)
    keep = np.isfinite(dst).all(axis=1)
    if mask is not None:
        keep &= mask[::step, ::step].reshape(-1)
    return src[keep], dst[keep]


def _with_hull(H: np.ndarray, inliers: np.ndarray, h: int, w: int, min_hull: float) -> Fit:
    """``(H, hull)`` with the bool ``(h, w)`` convex hull of the inliers, or None when it covers less
    than ``min_hull`` of the frame."""
    hull = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(inliers).astype(np.int32)), 1)
    return (H, hull > 0) if hull.mean() >= min_hull else None


def area_ratio(H: np.ndarray, h: int, w: int) -> float:
    """How much a homography's local area scale varies over an ``h x w`` frame: max / min over the
    corners of ``det J(p) = det(H) / (h_3 . p)^3``; ``inf`` when it flips orientation somewhere (a
    surface seen by the camera from the projector's side cannot mirror the image).

    Example:
        >>> area_ratio(np.eye(3), 10, 10)
        1.0
    """
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], np.float64)
    det = np.linalg.det(np.asarray(H, np.float64)) / (corners @ np.asarray(H, np.float64)[2]) ** 3  # [4]
    return float(det.max() / det.min()) if (det > 0).all() else math.inf


def plane_agrees(plane: np.ndarray, flow: np.ndarray, textured: np.ndarray, px: float) -> bool:
    """Whether a homography's flow stays within ``px`` of the refined ``flow`` it was simplified from on 90 %
    of the ``textured`` pixels: only then is it the same explanation of the images with less noise. Where
    the residual moved the answer farther (a low-contrast pair whose residual wandered, a bent surface),
    a close score says only that the images cannot tell the two apart.

    Example:
        >>> f = np.zeros((4, 4, 2), np.float32)
        >>> plane_agrees(f, f + 1.0, np.ones((4, 4), bool), 2.0), plane_agrees(f, f + 3.0, np.ones((4, 4), bool), 2.0)
        (True, False)
    """
    gap = np.linalg.norm(plane - flow, axis=-1)[textured]
    return bool(gap.size) and float(np.percentile(gap, 90)) <= px


def near(mask: np.ndarray, radius: float) -> np.ndarray:
    """Pixels at most ``radius`` px (Euclidean) from a true pixel of ``mask``."""
    far = cv2.distanceTransform(np.where(mask, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    return far <= radius


def bound_outside(flow: np.ndarray, prior: np.ndarray, support: np.ndarray, bound: float) -> np.ndarray:
    """``flow`` where ``support`` is true; elsewhere moved at most ``bound`` px away from ``prior``.

    Example:
        >>> f = np.array([[[30.0, 40.0], [1.0, 0.0]]], np.float32)
        >>> bound_outside(f, np.zeros_like(f), np.array([[False, False]]), 5.0)[0].tolist()
        [[3.0, 4.0], [1.0, 0.0]]
    """
    d = flow - prior  # [H, W, 2]
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    scale = np.where(support[..., None], 1.0, np.minimum(1.0, bound / np.maximum(n, 1e-6)))
    return (prior + d * scale).astype(np.float32)


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
    moved = cv2.remap(
        base, x + residual[..., 0], y + residual[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return (residual + moved).astype(np.float32)


def texture_weight(gray: np.ndarray, floor: float = 0.0, sigma: float = 3.0) -> np.ndarray:
    """Per-pixel weight in [0, 1]: local gradient energy (Sobel, squared, Gaussian-averaged) relative
    to the frame's median or to ``floor``, whichever is larger, capped at 1.

    The floor makes the weight absolute where the frame is mostly flat: a picture covering a quarter of
    the frame, or one with almost no contrast, has a median energy near zero, and relative to that
    noise would count as texture. ``floor = 64 g^2`` is the energy of a ramp of ``g`` grey levels per
    pixel (a Sobel derivative is 8 times the slope).
    """
    g = gray.astype(np.float32)
    energy = cv2.GaussianBlur(cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2, (0, 0), sigma)
    return np.minimum(energy / (max(float(np.median(energy)), floor) + 1e-3), 1.0)


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
    bend: float = 0.0,
) -> np.ndarray:
    """Robust weighted least-squares cubic B-spline fit of a 2-channel field.

    Args:
        field: float ``(H, W, 2)``; fitted on every ``step``-th pixel.
        weight: float ``(H, W)`` >= 0, the confidence of each pixel.
        grid: control points ``(kx, ky)``.
        robust: Cauchy scale (field units) of the reweighting after the first solve.
        ridge: Tikhonov weight towards zero on the control values.
        iterations: weighted solves (the first unweighted by residuals).
        bend: weight of a second-difference penalty on the control values (a P-spline): bridges
            regions without data smoothly instead of pulling them to zero.

    Returns:
        float32 ``(H, W, 2)``, the spline evaluated at every pixel.
    """
    design = spline_design(field.shape[0], field.shape[1], tuple(grid), step)
    f, w0 = design.samples(field, weight)
    with one_blas_thread():
        return design.evaluate(design.solve(f, w0, robust, ridge, iterations, bend))


def one_blas_thread():
    """A context with one BLAS thread: the spline's products are small, and a second thread contending
    with torch's OpenMP workers (or another process) made one fit take 1.5-4 s instead of 50 ms on the
    2-core VM."""
    return _BLAS.limit(limits=1, user_api="blas")


@lru_cache(maxsize=8)
def spline_design(h: int, w: int, grid: tuple[int, int], step: int) -> SplineDesign:
    """The :class:`SplineDesign` of one frame size, grid and step, built once (its arrays are not written)."""
    return SplineDesign(h, w, grid, step)


class SplineDesign:
    """A cubic B-spline on one frame size and grid, sampled every ``step`` px, and its weighted robust solve.

    The basis is a tensor product, so the normal equations are built separably (one pass over the
    sample rows per basis pair) instead of from the dense ``(N, K)`` design matrix: a few milliseconds
    for a 14 x 11 grid on 12,000 samples.
    """

    def __init__(self, h: int, w: int, grid: tuple[int, int], step: int) -> None:
        kx, ky = grid
        self.grid, self.step = grid, step
        self.By, self.Bx = bspline_basis(h, ky), bspline_basis(w, kx)  # [H, ky], [W, kx]
        self.by, self.bx = self.By[::step], self.Bx[::step]  # [h', ky], [w', kx]: at the samples
        self.byy = (self.by[:, :, None] * self.by[:, None, :]).reshape(len(self.by), ky * ky)  # [h', ky ky]
        self.bxx = (self.bx[:, :, None] * self.bx[:, None, :]).reshape(len(self.bx), kx * kx)  # [w', kx kx]
        dy = np.diff(np.eye(ky), 2, axis=0)  # second differences along y and along x of the control grid
        dx = np.diff(np.eye(kx), 2, axis=0)
        D = np.concatenate([np.kron(dy, np.eye(kx)), np.kron(np.eye(ky), dx)])  # [M, K]
        self.penalty = D.T @ D  # [K, K]
        for a in (self.By, self.Bx, self.by, self.bx, self.byy, self.bxx, self.penalty):
            a.flags.writeable = False  # shared between callers by spline_design's cache

    def samples(self, field: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The field's ``(h', w', 2)`` samples (non-finite ones at weight 0) and their ``(h', w')`` weights."""
        st = self.step
        f = field[::st, ::st].astype(np.float64)
        w0 = weight[::st, ::st].astype(np.float64)
        ok = np.isfinite(f).all(axis=-1)
        return np.where(ok[..., None], f, 0.0), np.where(ok, w0, 0.0)

    def at_samples(self, c: np.ndarray) -> np.ndarray:
        """The spline of control values ``c`` ``(ky, kx, 2)`` at the samples, ``(h', w', 2)``."""
        return np.stack([self.by @ c[..., i] @ self.bx.T for i in range(2)], axis=-1)

    def solve(
        self, f: np.ndarray, w0: np.ndarray, robust: float, ridge: float, iterations: int, bend: float = 0.0
    ) -> np.ndarray:
        """Control values ``(ky, kx, 2)``: iteratively reweighted (Cauchy) least squares with ridge and
        bend penalties."""
        kx, ky = self.grid
        reg = ridge * np.eye(kx * ky) + bend * self.penalty
        fit = np.zeros_like(f)
        for it in range(iterations):
            wi = w0 if it == 0 else w0 / (1 + (np.linalg.norm(f - fit, axis=-1) / robust) ** 2)  # [h', w']
            normal = (self.byy.T @ (wi @ self.bxx)).reshape(ky, ky, kx, kx)  # [i, k, j, l]
            normal = normal.transpose(0, 2, 1, 3).reshape(kx * ky, kx * ky)  # rows (i, j), columns (k, l)
            rhs = np.stack([self.by.T @ (f[..., i] * wi) @ self.bx for i in range(2)], axis=-1)  # [ky, kx, 2]
            c = np.linalg.solve(normal + reg, rhs.reshape(kx * ky, 2)).reshape(ky, kx, 2)
            fit = self.at_samples(c)
        return c

    def evaluate(self, c: np.ndarray) -> np.ndarray:
        """The spline of control values ``c`` at every pixel, float32 ``(H, W, 2)``."""
        return np.stack([self.By @ c[..., i] @ self.Bx.T for i in range(2)], axis=-1).astype(np.float32)


def fit_detail(
    remainder: np.ndarray,
    weight: np.ndarray,
    grid: tuple[int, int],
    bends: tuple[float, ...],
    step: int,
    robust: float,
    block: int = 32,
    gain: float = 0.05,
) -> tuple[np.ndarray, float | None]:
    """Surface detail finer than the coarse spline (a short-period bend), only where the data carry it.

    ``remainder`` (what the coarse spline left of the DIS residual) is fitted by a P-spline on the
    fine ``grid`` at each penalty weight in ``bends``; two-fold cross-validation on a checkerboard of
    ``block`` px blocks (fit on one colour, score the other: DIS's errors are correlated over its
    patches, so neighbouring pixels cannot vouch for each other) scores each against leaving the
    remainder alone. The winner must lower the held-out robust loss (texture-weighted Cauchy) by
    ``gain``; otherwise no detail is added. The detail fades out where ``weight`` has no data within
    about half a knot spacing (a P-spline extrapolates its slopes; beyond the data that is a guess).

    Returns:
        ``(detail, bend)``: float32 ``(H, W, 2)`` (zeros when nothing wins) and the chosen penalty
        (None: none).
    """
    h, w = remainder.shape[:2]
    design = spline_design(h, w, tuple(grid), step)
    f, w0 = design.samples(remainder, weight)
    y, x = np.mgrid[0:h:step, 0:w:step]
    colour = ((y // block) + (x // block)) % 2 > 0  # [h', w']

    def held_out(pred: np.ndarray, mask: np.ndarray) -> float:
        e = np.linalg.norm(f - pred, axis=-1)
        return float((w0 * mask * np.log1p((e / robust) ** 2)).sum())

    with one_blas_thread():
        losses = {None: held_out(0 * f, colour) + held_out(0 * f, ~colour)}
        for bend in bends:
            fits = [design.at_samples(design.solve(f, w0 * ~m, robust, 1e-3, 3, bend)) for m in (colour, ~colour)]
            losses[bend] = held_out(fits[0], colour) + held_out(fits[1], ~colour)
        best = min(losses, key=losses.get)
        if best is None or losses[best] > (1 - gain) * losses[None]:
            return np.zeros_like(remainder, dtype=np.float32), None
    sigma = 0.5 * max(h / (grid[1] - 3), w / (grid[0] - 3))  # half a knot spacing, px
    near_data = ramp(cv2.GaussianBlur(weight.astype(np.float32), (0, 0), sigma), 0.05, 0.3)
    with one_blas_thread():
        detail = design.evaluate(design.solve(f, w0, robust, 1e-3, 3, best))
    return detail * near_data[..., None], best


def unverified(claimed: np.ndarray, repeating: np.ndarray | None, textured: np.ndarray) -> str:
    """Why a pair that passed no check is not registered: a repeating pattern when most of its texture
    repeats itself (no check can tell the right period from the next), else ``no region verified``."""
    repeats = 0.0 if repeating is None or not textured.any() else float(repeating[textured].mean())
    if repeats >= 0.5:
        period = "a flow one period off would pass every check"
        return f"repeating pattern: {100 * repeats:.0f}% of the projected texture repeats itself ({period})"
    return f"no region verified ({100 * claimed.mean():.1f}%)"


def repeating(gray: np.ndarray, fine_peak: float = 0.85, coarse_peak: float = 0.93) -> np.ndarray:
    """Pixels where the image repeats itself, bool ``(H, W)``: :func:`periodicity` at least ``fine_peak``
    in the 64 px window or ``coarse_peak`` in the 128 or 256 px windows (those that fit the image).

    The coarse windows ask for a closer repeat: a photograph of a regular thing (a brick wall) scores
    0.83-0.91 there, from its courses, while its detail differs from one brick to the next, which the
    photometric check sees; a repeated digital motif scores 0.98-1.00 (docs/model.md)."""
    out = np.zeros(gray.shape, bool)
    for tile, peak in ((64, fine_peak), (128, coarse_peak), (256, coarse_peak)):
        if min(gray.shape) >= tile:  # a smaller image: no such window
            out |= periodicity(gray, tile) >= peak
    return out


def periodicity(gray: np.ndarray, tile: int = 64) -> np.ndarray:
    """Per pixel, how well the image repeats itself around it, float32 ``(H, W)`` in [0, 1]: near 1 on a
    grating, a checkerboard or a tiled motif, whose match one period away is as good as the true
    one; low on an edge or a ramp, which stay similar under every move along them (the aperture
    problem, which the smooth surface model resolves from their neighbours).

    Each ``tile`` x ``tile`` window (side by side, Hann-weighted) gives its autocorrelation (FFT,
    zero-padded, divided by the window's own so a shift is not penalised for the smaller overlap);
    the score is its highest value outside the central lobe (the connected region >= 0.3 around zero
    shift, which holds an edge's ridge), within half a tile; the tiles' scores are interpolated over
    the frame. The window's edge weights leave periods up to about ``0.45 tile`` visible (64: 28 px).

    Example:
        >>> x = np.arange(128, dtype=np.float32)
        >>> grating = np.tile(128 + 100 * np.sin(2 * np.pi * x / 7), (96, 1)).astype(np.uint8)
        >>> bool(periodicity(grating)[48, 64] > 0.8)
        True
        >>> edge = np.tile(np.where(x < 64, 40, 200), (96, 1)).astype(np.uint8)
        >>> bool(periodicity(edge)[48, 64] < 0.3)
        True
    """
    h, w = gray.shape
    if min(h, w) < tile:
        return np.zeros((h, w), np.float32)
    g = gray.astype(np.float32)
    starts = [np.unique(np.r_[np.arange(0, n - tile + 1, tile), n - tile]) for n in (h, w)]
    hann = np.outer(np.hanning(tile), np.hanning(tile)).astype(np.float32)
    tiles = np.stack([g[y : y + tile, x : x + tile] for y in starts[0] for x in starts[1]])  # [T, tile, tile]
    tiles = (tiles - tiles.mean(axis=(1, 2), keepdims=True)) * hann

    def autocorrelation(a: np.ndarray) -> np.ndarray:  # [..., 2 tile, 2 tile], zero shift at the centre
        power = np.abs(np.fft.rfft2(a, s=(2 * tile, 2 * tile))) ** 2
        return np.fft.fftshift(np.fft.irfft2(power, s=(2 * tile, 2 * tile)), axes=(-2, -1))

    c = tile  # the zero shift after fftshift
    span = slice(c - tile // 2, c + tile // 2 + 1)
    window = autocorrelation(hann)[span, span]
    ac = autocorrelation(tiles)[:, span, span] / np.maximum(window, 1e-6)  # [T, tile + 1, tile + 1]
    ac = ac / np.maximum(ac[:, tile // 2, tile // 2 : tile // 2 + 1, None], 1e-6)
    ac[:, window < 0.25 * window.max()] = 0.0
    scores = np.zeros(len(tiles), np.float32)
    for i, a in enumerate(ac):
        if not np.isfinite(a).all() or tiles[i].std() < 1e-3:
            continue
        _, labels = cv2.connectedComponents((a >= 0.3).astype(np.uint8), connectivity=8)
        outside = labels != labels[tile // 2, tile // 2]
        scores[i] = float(np.clip(a[outside].max(initial=0.0), 0.0, 1.0))
    grid = scores.reshape(len(starts[0]), len(starts[1]))
    centres = [s + tile / 2 for s in starts]  # tile centres, px
    x, y = (
        np.interp(np.arange(w), centres[1], np.arange(len(centres[1]))),
        np.interp(np.arange(h), centres[0], np.arange(len(centres[0]))),
    )
    mx, my = np.meshgrid(x.astype(np.float32), y.astype(np.float32))
    return cv2.remap(grid, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def local_ncc(gray0: np.ndarray, gray1: np.ndarray, sigma: float = 7.0) -> np.ndarray:
    """Local normalised cross-correlation of two aligned images (Gaussian window ``sigma``), float32
    ``(H, W)`` in [-1, 1]: 1 is a match up to local gain and offset, about 0 no match (and 0 where
    either image is flat)."""
    a, b = gray0.astype(np.float32), gray1.astype(np.float32)

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, (0, 0), sigma)

    ma, mb = blur(a), blur(b)
    cov = blur(a * b) - ma * mb
    var = np.maximum((blur(a * a) - ma * ma) * (blur(b * b) - mb * mb), 1e-2)
    return cov / np.sqrt(var)


def alignment_score(
    gray0: np.ndarray, gray1: np.ndarray, flow: np.ndarray, sigma: float = 7.0, weight: np.ndarray | None = None
) -> float:
    """How well ``flow`` aligns the pair: the mean of :func:`local_ncc` between ``gray0`` and ``gray1``
    warped back by ``flow``, weighted by ``weight`` (the projected image's texture; None: uniform).

    Weighting by texture makes the score count coverage: a flow that aligns one textured corner
    and misaligns the rest of the texture scores by the whole texture, not by a median that flat
    regions (NCC about 0 under any flow) dominate.
    """
    return weighted_ncc(gray0, warp_back(gray1, flow), sigma, weight)


def weighted_ncc(gray0: np.ndarray, warped: np.ndarray, sigma: float, weight: np.ndarray | None) -> float:
    """:func:`alignment_score` of an image already warped into the projector frame."""
    return weighted_mean(local_ncc(gray0, warped, sigma), weight)


def weighted_mean(values: np.ndarray, weight: np.ndarray | None) -> float:
    """The mean of ``values`` weighted by ``weight`` (None: uniform)."""
    if weight is None:
        return float(values.mean())
    return float((values * weight).sum() / max(float(weight.sum()), 1e-6))
