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
frame's width); docs/model.md describes each step and what it is for.

Convention: flows are float32 ``(H, W, 2)``, forward, projected -> captured, pixels:
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np

from .. import ProjregError
from ..geometry.frames import resize_flow, shrink
from ..geometry.homography import SiftHomography, area_ratio, fit_affine, fit_homography, fit_step, homography_flow
from ..geometry.images import (
    divide_albedo,
    local_ncc,
    near,
    normalize_contrast,
    texture_weight,
    to_gray,
    weighted_mean,
    weighted_ncc,
)
from ..geometry.splines import fit_bspline, fit_detail
from ..geometry.warp import compose, warp_back
from ..prediction import CONFIDENT, Prediction
from .confidence import gap_confidence, pixel_confidence
from .config import MIN_SIDE, RefineConfig, RefineInfo
from .evidence import bound_outside, plane_agrees, repeating, unverified


class GeometricRefiner:
    """Refines network flows (module docstring); holds one DIS instance, so one refiner per thread."""

    def __init__(self, config: RefineConfig | None = None) -> None:
        self.config = config or RefineConfig()
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOpticalFlow_PRESET_MEDIUM)
        self._sift = SiftHomography() if self.config.sift_pass else None

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
                frame's: :mod:`projreg.inference.track`).
            identity: also try the identity and the SIFT hypotheses (tracking leaves them out while
                ``flow`` has a homography fit; its ``hypothesis`` is then "network" unless that fit
                failed); the config's ``identity_pass`` / ``sift_pass`` off leave them out always
                (``FAST_REFINE``).

        Returns:
            The :class:`~projreg.prediction.Prediction` (float32 ``(H, W, 2)`` forward flow, the pixels
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
        h, w = projected.shape[:2]
        H, status, _ = self._sift(to_gray(projected), to_gray(captured))
        if status != "ok":
            return {}
        flow = homography_flow(H, h, w)
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
        """Per-pixel confidence in [0, 1] of candidate ``best`` (:func:`projreg.refine.confidence.pixel_confidence`):
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
        :func:`projreg.refine.confidence.gap_confidence`) where ``flow`` stays within ``bridge_px`` of the homography
        fitted to it on its claimed pixels (``conf >= CONFIDENT``); ``conf`` itself when that fit fails.

        In a flat gap the answer is the surface model's interpolation; where the plane of the verified
        region says the same, two models of the gap agree and the gap is claimed. Where the surface bends
        away from that plane, or the answer is held to a guess (a region farther from texture than
        ``support_margin``), they part and the claim stays with the checks (docs/model.md, "The bridge")."""
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
        there, and is not counted (docs/model.md, "Confidence"). ``memo``: as
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


