"""Geometric refinement of a network flow: a staged estimator over one pair's context.

A projector-camera map is a homography (a plane seen by two pinhole devices) bent by lens distortion
and by the shape of the surface, both smooth over the frame. The network's flow finds that map
globally, through occlusions and large displacements, but only to a few pixels. This stage keeps what
the network is good at and takes the precision from the images. :meth:`GeometricRefiner.predict_info`
reads as the algorithm:

1. **Context** (:class:`~projreg.refine.context.PairContext`): the pair's gray views (normalised for
   local contrast, plain, and with the wall's reflectance divided out), its texture evidence and
   support, built once; a pair without texture stops here, not registered.
2. **Propose** (:mod:`~projreg.refine.candidates`): starts, each a homography: the one fitted to the
   network's flow; the identity and a SIFT + RANSAC homography of the pair form a second stage.
3. **Refine**: from each start on each view, a DIS residual, a refitted homography, and the smooth
   surface model of what remains (B-spline, and a cross-validated finer P-spline); the refitted
   homography alone competes where it stands for its candidate. A stage's candidates run side by side
   on ``search.workers`` threads.
4. **Score and select** (:mod:`~projreg.refine.selection`): texture-weighted mean local NCC of the
   projected image and the captured image warped back; the best wins, unless a homography alone scores
   within ``plane_margin`` of it.
5. **Verify** (:mod:`~projreg.refine.verify`): per-pixel checks (local NCC, forward-backward
   residual, rivals that explain the images as well), spread over the texture's neighbourhood; pixels
   where the projected image repeats itself are never claimed.
6. **Escalate**: when the network's answer claims less than ``escalate_below`` of the textured pixels
   it keeps in the frame, the second stage's starts are refined and selected with the first's;
   otherwise they are not tried. With ``align.direct`` (``balanced``, the default) the first stage aligns
   the network's start directly and polishes it with DIS (:func:`~projreg.refine.candidates.align_view`,
   :func:`~projreg.refine.candidates.polish`);
   an escalation drops those candidates unless they claimed ``keep_direct_at`` of the texture (``accurate``
   escalates always and keeps them where ``balanced`` would have stopped), and may restart from the
   network's flow at a finer resolution (``finer``) with DIS on every view.
7. **Extend**: a partial answer's verified plane starts one more hypothesis (``grown``); a registered
   answer also claims wide flat gaps where its plane agrees with it (the bridge).
8. **Re-align**: a DIS-refined winner aligned to the images directly from its own smooth surface, the
   fine grid alone at full size (:func:`~projreg.refine.candidates.realign`), kept where it stays within
   ``align.trust_px`` of it; started on the pool as soon as such a winner is selected, beside its
   verification, and stopped when the search moves on (:class:`~projreg.refine.search.Search`). A winner
   whose checks verify nothing is left as it is.
9. **Verdict**: registered when the claim covers at least ``registered_above`` of the frame and
   ``registered_windows`` of the checks' windows (:func:`~projreg.refine.evidence.registers`), the capture
   is not the projection mirrored (:mod:`~projreg.refine.handedness`), and a claim under ``confirm_below``
   of the frame stays where the frame's alignment started from it leaves it
   (:func:`~projreg.refine.candidates.stays`); otherwise nothing is claimed (and where nothing verified,
   the answer is the homography of the network's flow, its smoothest statement). A registered answer's
   claim is then limited, where it bends, to pixels near texture that fixes a position within one check
   window (:func:`~projreg.refine.verify.pinned`): a curve alone slides along itself.

A pair longer than ``images.max_side`` runs stages 1-8 shrunk to it; with ``images.verify_full``
(``balanced``: 512 px), or where the winner claims less than ``images.verify_full_below`` of the visible
texture (``fast``: half), the candidates are then resized to the pair's own grid and the winner verified there
(stage 5 again, at full resolution) before the verdict.

docs/model.md describes each stage, its parameters (:mod:`~projreg.refine.config`) and what it is for.

Convention: flows are float32 ``(H, W, 2)``, forward, projected -> captured, pixels:
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import replace

import cv2
import numpy as np

from ..errors import ProjregError
from ..geometry.frames import resize_flow, shrink
from ..geometry.homography import SiftHomography, homography_flow, rescaled
from ..geometry.linalg import on_one_blas_thread
from ..prediction import CONFIDENT, Prediction
from . import verify
from .candidates import (
    Candidate,
    RefineInfo,
    Start,
    grown_start,
    identity_start,
    network_starts,
    realign,
    sift_start,
    stays,
)
from .config import DEFAULT_QUALITY, MIN_SIDE, QUALITIES, RefineConfig
from .context import PairContext, Projected
from .evidence import registers, repeat_jobs, repeats_in, unverified
from .handedness import Features, Handedness, check
from .search import Search
from .selection import rivals, select
from .stages import gather, stage, submit
from .workers import Workers


class GeometricRefiner:
    """Refines network flows (module docstring); one refiner may serve one thread at a time.

    ``config``: the refinement's settings (default: the default quality's, :data:`QUALITIES`)."""

    def __init__(self, config: RefineConfig | None = None) -> None:
        self.config = config or QUALITIES[DEFAULT_QUALITY].refine
        self._sift = SiftHomography() if self.config.search.sift else None
        self._workers = Workers(self.config.search.workers)
        self._sides: dict[tuple[int, ...], Projected] = {}  # the last projected image's side, by size (the pair's
        # own and shrunk, two at most): reused while it repeats

    def refine(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, RefineInfo]:
        """The refined flow of one pair and what was chosen (:meth:`predict_info` without the verdict)."""
        pred, info = self.predict_info(projected, captured, flow)
        return pred.flow, info

    def predict(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> Prediction:
        """The refined flow with the pixels it claims and whether the pair registered (:meth:`predict_info`)."""
        return self.predict_info(projected, captured, flow)[0]

    @on_one_blas_thread  # the refinement's threads are its pool's: BLAS threads beside them only contend
    def predict_info(
        self,
        projected: np.ndarray,
        captured: np.ndarray,
        flow: np.ndarray,
        identity: bool = True,
        finer: Callable[[], np.ndarray] | None = None,
    ) -> tuple[Prediction, RefineInfo]:
        """Refine one pair: flow, per-pixel confidence, registered or not, and what was chosen.

        Args:
            projected, captured: uint8 RGB ``(H, W, 3)`` of one size.
            flow: the network's flow for the pair, float ``(H, W, 2)`` (or, tracking, the previous
                frame's: :mod:`projreg.inference.track`).
            identity: allow the second stage's starts (the identity and SIFT; tracking leaves them out
                while ``flow`` has a homography fit); the config's ``search`` flags leave them out always.
            finer: the network's flow for the pair at a finer resolution, float ``(H, W, 2)``, called only
                when the first stage escalates: the second stage starts from it instead of ``flow``.

        Returns:
            The :class:`~projreg.prediction.Prediction` (float32 ``(H, W, 2)`` forward flow, the pixels
            whose confidence is at least ``CONFIDENT``, ``registered`` and why not) and the
            :class:`~projreg.refine.candidates.RefineInfo` (its ``confidence`` is the per-pixel map). A
            pair whose projected image has texture on less than ``textureless_below`` of the frame is
            not registered: the flow is zero and nothing is claimed. Pairs with a side under
            ``MIN_SIDE`` come back unchanged and unclaimed (``hypothesis="skipped"``).
        """
        h, w = projected.shape[:2]
        if projected.shape != captured.shape or projected.ndim != 3 or flow.shape != (h, w, 2):
            raise ProjregError(
                f"refine needs projected, captured (H, W, 3) and flow (H, W, 2) of one size, got "
                f"{projected.shape}, {captured.shape}, {flow.shape}"
            )
        flow = np.asarray(flow, np.float32)
        if self._searched_shrunk(h, w):
            return self._predict_shrunk(projected, captured, flow, identity, finer)
        return self._predict_at(projected, captured, flow, identity, finer)

    def _predict_at(
        self,
        projected: np.ndarray,
        captured: np.ndarray,
        flow: np.ndarray,
        identity: bool,
        finer: Callable[[], np.ndarray] | None,
        scale: float = 1.0,
    ) -> tuple[Prediction, RefineInfo]:
        """:meth:`predict_info` on the pair as given; ``scale``: the user's pixels per pixel of it, where it is
        the user's pair shrunk and verified here (:class:`~projreg.refine.context.PairContext`)."""
        h, w = projected.shape[:2]
        none = np.zeros((h, w), np.float32)
        if min(h, w) < MIN_SIDE:
            return Prediction(flow, none > 0, False, "too small", none), RefineInfo("skipped", "", {}, none, 0.0)
        fitting = self._workers.submit(network_starts, self.config, flow)  # beside the context
        ctx = PairContext.build(projected, captured, self.config, self._projected(projected), scale)
        if ctx.share < self.config.images.textureless_below:
            fitting.cancel()
            return textureless(flow, ctx.share)
        search = self._search(ctx, projected, captured, fitting, identity, finer)
        return self._verdict(search)

    def _search(
        self,
        ctx: PairContext,
        projected: np.ndarray,
        captured: np.ndarray,
        fitting: Future,
        identity: bool,
        finer: Callable[[], np.ndarray] | None,
    ) -> Search:
        """Propose, refine, score and select, verify, escalate, grow, re-align (module docstring, stages 2-8).

        ``fitting``: the network's starts (:func:`~projreg.refine.candidates.network_starts`), found on the
        pool while the context was built. With ``align.direct`` the first stage aligns its starts directly
        on ``align.views``; the second adds the DIS-refined candidates of every start and view."""
        cfg, conf_cfg = self.config, self.config.confidence
        measure = conf_cfg.periodic and ctx.side.repeats is None  # once per projected image ...
        periodic = (conf_cfg.periodic_peak, conf_cfg.coarse_peak, conf_cfg.periodic_tiles)
        periodic += (conf_cfg.periodic_lobe, conf_cfg.periodic_overlap)
        # ... on the pool, each window size a job, beside the network's start
        jobs = repeat_jobs(ctx.normalised[0], *periodic) if measure else []
        pending = [self._workers.submit(repeats_in, *job) for job in jobs]
        mirror = self._workers.submit(self._handedness, ctx) if conf_cfg.mirror_side is not None else None
        network, first, usable = fitting.result()
        views, direct = list(ctx.views()), cfg.align.direct
        first_views = list(cfg.align.views) if direct else [v for v in views if v in cfg.search.first_views]
        more = identity and (cfg.search.identity or cfg.search.sift)
        one_stage = not direct and (cfg.search.escalate_below >= 1 or not first_views)
        if one_stage:  # every start on every view, in one stage
            second = self._second_starts(ctx, projected, captured, usable) if more else []
            cands = stage(ctx, self._workers, first + second, views, False)
            stages = ["network"] + (["more starts"] if more else [])
        else:
            cands, stages = stage(ctx, self._workers, first, first_views, direct), ["network"]
        search = Search(ctx, network, cands, {}, stages, mirror=mirror)
        if measure:
            repeats = np.zeros(ctx.shape, bool)
            for job in pending:
                repeats |= job.result()
            ctx.side.repeats = repeats
        search.repeats = ctx.side.repeats
        self._reselect(search, ahead=(lambda best: best.polished) if direct and cfg.align.realign else None)
        rest = views if direct else [v for v in views if v not in first_views]  # DIS's views still to try
        claimed = search.claimed()
        if not one_stage and (more or rest) and claimed < cfg.search.escalate_below:
            search.drop_ahead()  # the first stage's candidates do not go on: its winner's re-alignment stops
            if finer is not None:  # the network's finer flow: a better start for the search, on every view
                search.network, first, usable = network_starts(cfg, resize_flow(finer(), (*ctx.shape, 2)))
                rest = views
            # SIFT's start is found on the pool while the finer start's views are refined beside it
            found = self._workers.submit(self._second_starts, ctx, projected, captured, usable) if more else None
            refining = submit(ctx, self._workers, first, rest)
            second = found.result() if found else []
            refining_second = submit(ctx, self._workers, second, views)  # queued before the first are gathered
            if direct and claimed < cfg.search.keep_direct_at:  # an aligned answer that did not verify the frame
                search.cands = []  # is not kept as a rival of DIS's
            direct = False
            search.cands += gather(ctx, first, refining) + gather(ctx, second, refining_second)
            search.stages.append("more starts")
            self._reselect(search)
        # an aligned first stage that verified what ``settle_at`` asks: nothing left to grow or re-align
        settled = direct and claimed >= cfg.search.settle_at
        grow = cfg.search.grow and not settled
        grown = grown_start(ctx, search.best.flow, search.conf >= CONFIDENT) if grow else None
        if grown is not None:  # the verified region's plane, refined again, may verify more of the frame
            search.cands += stage(ctx, self._workers, [grown], first_views if direct else views, direct)
            search.stages.append("grown")
            self._reselect(search, ahead=(lambda best: True) if cfg.align.realign else None)  # re-aligned next
        if cfg.align.realign and (search.best.polished or not settled):  # DIS's noise under the spline
            self._realign(search)
        else:
            search.drop_ahead()  # started for a winner that was not kept
        return search

    def _realign(self, search: Search) -> None:
        """The winner replaced by its re-alignment (:func:`~projreg.refine.candidates.realign`) when kept;
        the one started ahead where it is this winner's. A winner whose checks verify less than
        ``registered_above`` of the frame is not re-aligned: there is no verified basin to refine it in."""
        ctx, ahead = search.ctx, search.ahead
        if (search.conf >= CONFIDENT).mean() < self.config.confidence.registered_above:
            search.drop_ahead()
            return
        if ahead is not None and ahead[0] is search.best:
            again = ahead[1].result()
        else:
            search.drop_ahead()
            again = realign(ctx, search.best)
        if again is not None:
            search.cands = [again if c is search.best else c for c in search.cands]
            search.best, search.scores[again.key] = again, ctx.score(again.key, again.flow)
            search.stages.append("realigned")
            search.conf = self.confidence(ctx, search.cands, search.scores, again, search.repeats)

    def _verdict(self, search: Search) -> tuple[Prediction, RefineInfo]:
        """Registered or not, and why; the bridge for a registered answer; the network's homography for one
        that verifies nothing (module docstring, stages 7 and 9). A claim too small to tell from chance
        (:func:`~projreg.refine.evidence.registers`) is not registered and claims nothing, but where it covers
        ``registered_above`` of the frame the search's answer stays the flow."""
        ctx, cfg, scores = search.ctx, self.config.confidence, search.scores
        net = [c for c in search.cands if c.hypothesis == "network"]
        if (search.conf >= CONFIDENT).mean() < cfg.registered_above and net and search.best.hypothesis != "network":
            # nothing verified (e.g. content washed out by daylight): the scores carry no evidence,
            # so the answer stays with the network's hypothesis rather than another start's
            search.best = max(net, key=lambda c: scores[c.key])
            search.conf = self.confidence(ctx, search.cands, scores, search.best, search.repeats)
        best, conf = search.best, search.conf
        claimed = conf >= CONFIDENT
        verified = claimed.mean() >= cfg.registered_above  # some region verified: the search's answer stands
        # the claim's pinning (below) is made on the pool beside the verdict's checks, used if it registers (it
        # reads the checks' maps, made with the answer's confidence: no DIS is queued from the pool)
        pins = None
        if cfg.pin and verified:
            pins = self._workers.submit(verify.pinned, ctx, search.cands, scores, best, self._workers.dis_flows)
        why = "" if self._registers(claimed) else unverified(claimed, search.repeats, ctx.textured, cfg.repeating_share)
        if search.mirror is not None and not why:
            why = self._mirrored(search)
        elif search.mirror is not None:
            search.mirror.cancel()  # not asked: the pair is not registered anyway
        if not why and claimed.mean() < cfg.confirm_below:  # a small claim: is it the frame's alignment too?
            why = unconfirmed(claimed, stays(ctx, best.flow, claimed), cfg.confirm_share, self.config.align.trust_px)
        if not why and cfg.bridge:  # the answer's flat gaps, where two models of them agree
            conf = verify.bridged(ctx, conf, best, search.cands, scores, search.repeats, self._workers)
            search.stages.append("bridge")
        if pins is not None and not why:  # the claim is where the texture also pins the answer (a curve alone
            # slides along itself on a bent surface): a precision of the claim, not the verdict on the registration
            conf = conf * pins.result()
        elif pins is not None:
            pins.cancel()
        claimed = conf >= CONFIDENT
        if not verified and search.network.H is not None:
            # nothing verified: residuals fitted on images that carry no evidence only add noise, and the
            # homography of the network's own flow is the smoothest statement of its hypothesis
            best = Candidate("network", "homography", homography_flow(search.network.H, *ctx.shape), plane=True)
            scores[best.key] = ctx.score(best.key, best.flow)
        # a pair reported as not registered claims nothing: a few stray pixels passing the checks are not
        # a registration the user can rely on (the confidence map in RefineInfo keeps them)
        pred = Prediction(best.flow, claimed if not why else np.zeros_like(claimed), not why, why, conf)
        return pred, RefineInfo(best.hypothesis, best.label, scores, conf, ctx.share, tuple(search.stages))

    def _handedness(self, ctx: PairContext) -> Handedness:
        """The pair's direct and mirrored SIFT consensus (:mod:`~projreg.refine.handedness`) on its images
        shrunk to ``confidence.mirror_side``; the projected image's features are kept with its side."""
        cfg = self.config.confidence
        if ctx.side.features is None:
            ctx.side.features = Features.of(ctx.side.plain, cfg.mirror_side)
        return check(ctx.side.features, ctx.plain[1], cfg.mirror_side, cfg.mirror_inliers, cfg.mirror_ratio)

    def _mirrored(self, search: Search) -> str:
        """Why the search's registered answer is a mirrored capture's (``""``: it is not). Mirrored when the
        mirrored SIFT consensus is ``mirror_inliers`` strong, or ``mirror_scored`` strong and its homography
        scores above the answer (:mod:`~projreg.refine.handedness`); both ``mirror_ratio`` times the direct."""
        cfg, ctx, best = self.config.confidence, search.ctx, search.best
        hand: Handedness = search.mirror.result()
        if hand.is_mirrored(cfg.mirror_inliers, cfg.mirror_ratio):
            return mirrored(hand)
        if hand.mirror is None or not hand.is_mirrored(cfg.mirror_scored, cfg.mirror_ratio):
            return ""
        seen, answer = ctx.score("mirror", hand.mirror_flow(ctx.shape)), ctx.score(best.key, best.flow)
        return mirrored(hand, (seen, answer)) if seen > answer else ""

    def _registers(self, claimed: np.ndarray) -> bool:
        """Whether ``claimed`` registers the pair (:func:`~projreg.refine.evidence.registers`)."""
        cfg = self.config.confidence
        return registers(claimed, cfg.registered_above, cfg.registered_windows, self.config.selection.ncc_sigma)

    def confidence(
        self,
        ctx: PairContext,
        cands: list[Candidate],
        scores: dict[str, float],
        best: Candidate,
        repeats: np.ndarray | None = None,
    ) -> np.ndarray:
        """Per-pixel confidence in [0, 1] of candidate ``best`` (:func:`~projreg.refine.verify.confidence`).

        The maps its checks read are made side by side first: the local NCC of ``best`` and of its rivals on the
        pool, and DIS's round trip of ``best`` queued behind them."""
        margin = self.config.confidence.rival_margin
        maps = [self._workers.submit(ctx.ncc, c.key, c.flow) for c in [best, *rivals(cands, scores, best, margin)]]
        maps[0].result()  # the winner's warped image, which the round trip reads too
        ctx.round_trip(self._workers.dis_flows, best.key, best.flow)
        for job in maps:
            job.result()
        return verify.confidence(ctx, cands, scores, best, repeats, self._workers.dis_flows)

    def score(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> float:
        """The selection score of ``flow`` on a pair of uint8 RGB images, as :meth:`predict_info` scores its
        candidates: on the pair shrunk to ``images.max_side`` where it searches there (tracking compares
        the two)."""
        side = self.config.images.max_side
        if self._searched_shrunk(*projected.shape[:2]):
            projected, captured = shrink(projected, side), shrink(captured, side)
            flow = resize_flow(np.asarray(flow, np.float32), projected.shape)
        ctx = PairContext.build(projected, captured, self.config, self._projected(projected))
        return ctx.score("flow", np.asarray(flow, np.float32))

    def _second_starts(
        self, ctx: PairContext, projected: np.ndarray, captured: np.ndarray, usable: bool
    ) -> list[Start]:
        """The identity (unless already in the first stage) and SIFT's homography, as configured."""
        out = [identity_start(ctx.shape)] if self.config.search.identity and usable else []
        if self._sift is not None:
            found = sift_start(ctx, self._sift, projected, captured)
            out += [found] if found is not None else []
        return out

    def _reselect(self, search: Search, ahead: Callable[[Candidate], bool] | None = None) -> None:
        """Score the new candidates, select, and verify the winner. ``ahead``: which winners are re-aligned
        unless the search moves on; such a winner's re-alignment starts on the pool first, beside its
        verification (the same answer; a core's work overlapped with the checks')."""
        ctx, scores = search.ctx, search.scores
        scores.update({c.key: ctx.score(c.key, c.flow) for c in search.cands if c.key not in scores})
        search.best = select(search.cands, scores, self.config.selection.plane_margin)
        if ahead is not None and self._workers.count >= 2 and ahead(search.best):
            search.realign_ahead(self._workers)
        search.conf = self.confidence(ctx, search.cands, scores, search.best, search.repeats)

    def _searched_shrunk(self, h: int, w: int) -> bool:
        """Whether an ``h x w`` pair is searched shrunk to ``images.max_side``: when it is longer, unless that
        leaves a side under ``MIN_SIDE`` (a thin strip is refined at its own size)."""
        side = self.config.images.max_side
        return side is not None and max(h, w) > side and min(h, w) * side >= MIN_SIDE * max(h, w)

    def _projected(self, projected: np.ndarray) -> Projected:
        """The projected side of ``projected`` (:class:`~projreg.refine.context.Projected`): the last one
        when it is the same image (a tracked sequence, a folder of captures of one picture), else built."""
        side = self._sides.get(projected.shape)
        if side is None or not side.matches(projected):
            if projected.shape not in self._sides and len(self._sides) >= 2:  # the pair's size and its shrunk one
                self._sides.pop(next(iter(self._sides)))
            side = self._sides[projected.shape] = Projected.build(projected, self.config)
        return side

    def _predict_shrunk(
        self,
        projected: np.ndarray,
        captured: np.ndarray,
        flow: np.ndarray,
        identity: bool,
        finer: Callable[[], np.ndarray] | None,
    ) -> tuple[Prediction, RefineInfo]:
        """:meth:`predict_info` on the pair shrunk to ``images.max_side``; flow and confidence resized back
        (bilinear), the claimed pixels those whose resized confidence is at least ``CONFIDENT``, its checks'
        distances read in the pair's own pixels (:func:`~projreg.refine.verify.checks`). With
        ``images.verify_full``, or where the answer claims less than ``images.verify_full_below`` of the visible
        texture, the search's answer is verified again at the pair's own size instead (:meth:`_at_full_size`):
        its confidence and claim are the full-size checks'."""
        images, (h, w) = self.config.images, projected.shape[:2]
        small0, small1 = shrink(projected, images.max_side), shrink(captured, images.max_side)
        smaller = None if finer is None else lambda: resize_flow(finer(), small0.shape)
        scale = max(h, w) / max(small0.shape[:2])  # a verdict read on the shrunk pair: its checks' tolerance
        small_flow = resize_flow(flow, small0.shape)
        if min(small0.shape[:2]) < MIN_SIDE:  # a thin strip shrunk: its own answer, unchanged (_predict_at)
            pred, info = self._predict_at(small0, small1, small_flow, identity, smaller, scale)
        else:
            fitting = self._workers.submit(network_starts, self.config, small_flow)  # beside the context
            side, tolerance = self._projected(small0), 1.0 if images.verify_full else scale
            ctx = PairContext.build(small0, small1, self.config, side, tolerance)
            if ctx.share < images.textureless_below:
                fitting.cancel()
                pred, info = textureless(small_flow, ctx.share)
            else:
                searched = self._search(ctx, small0, small1, fitting, identity, smaller)
                if images.verify_full or searched.claimed() < images.verify_full_below:
                    return self._verdict(self._at_full_size(searched, projected, captured))
                pred, info = self._verdict(searched)
        conf = cv2.resize(info.confidence, (w, h), interpolation=cv2.INTER_LINEAR)  # [H, W]
        claimed = (conf >= CONFIDENT) if pred.registered else np.zeros((h, w), bool)
        pred = replace(pred, flow=resize_flow(pred.flow, projected.shape), claimed=claimed, confidence=conf)
        return pred, replace(info, confidence=conf)

    def _at_full_size(self, search: Search, projected: np.ndarray, captured: np.ndarray) -> Search:
        """A search made on the pair shrunk, brought to the pair's own size: its candidates' flows resized,
        their scores kept, the winner verified again there (the local checks at full resolution)."""
        shape = projected.shape
        ctx = PairContext.build(projected, captured, self.config, self._projected(projected))
        cands = [replace(c, flow=resize_flow(c.flow, shape)) for c in search.cands]
        best = cands[[c.key for c in search.cands].index(search.best.key)]
        H = None if search.network.H is None else rescaled(search.network.H, search.ctx.shape, shape)
        network = Start(search.network.name, H, resize_flow(search.network.prior, shape))
        repeats = search.repeats
        if repeats is not None:
            repeats = cv2.resize(repeats.astype(np.uint8), shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0
        out = Search(ctx, network, cands, dict(search.scores), search.stages + ["full size"], repeats, best)
        out.mirror = search.mirror
        out.conf = self.confidence(ctx, cands, out.scores, best, repeats)
        return out


def textureless(flow: np.ndarray, share: float) -> tuple[Prediction, RefineInfo]:
    """The answer for a pair whose projected image carries texture on ``share`` of the frame, under
    ``images.textureless_below``: not registered, a zero flow of ``flow``'s shape, nothing claimed."""
    none = np.zeros(flow.shape[:2], np.float32)
    why = f"textureless: {100 * share:.1f}% of the projected image carries texture"
    return Prediction(np.zeros_like(flow), none > 0, False, why, none), RefineInfo("none", "", {}, none, share)


def unconfirmed(claimed: np.ndarray, share: float, least: float, px: float) -> str:
    """Why a small claim is not a registration: under ``least`` of its textured pixels (``share``) stayed within
    ``px`` when the whole frame was aligned again from it (:func:`~projreg.refine.candidates.stays`)."""
    if share >= least:
        return ""
    return (
        f"unconfirmed: the {100 * claimed.mean():.1f}% of the frame that passes the checks moves when the whole frame "
        f"is aligned again from it ({100 * share:.0f}% of its textured pixels stay within {px:g} px): a chance match "
        "of a few regions, as a photo of another picture gives; if the picture is the right one, it has too little "
        "structure to register alone: a structured-light pass (projsynth patterns) gives every pixel its own evidence"
    )


def mirrored(hand: Handedness, scores: tuple[float, float] | None = None) -> str:
    """Why a pair whose capture is its projection mirrored is not registered; ``scores``: the mirrored
    homography's and the answer's, where they decided it."""
    weighed = "" if scores is None else f"; the mirror scores {scores[0]:.2f} against the answer's {scores[1]:.2f}"
    return (
        f"mirrored: the captured image is the projected one mirrored ({hand.mirrored} SIFT matches agree on a "
        f"mirror, {hand.direct} on a direct map{weighed}): turn the camera's mirroring off, or flip the captured "
        "images (a rear-projection screen filmed from the front)"
    )
