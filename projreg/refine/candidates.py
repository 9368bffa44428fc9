"""The refinement's starts and candidates: :class:`Start` (a hypothesis: a homography and the flow it came
from), :class:`Candidate` (a refined flow, or a homography alone), and the two stages that make them:
:func:`refine_start` (DIS) and :func:`align_view` with :func:`polish` (direct alignment).

Convention: flows float32 ``(H, W, 2)``, forward, projected -> captured, pixels; homographies 3 x 3,
projected -> captured.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..geometry.align import align
from ..geometry.frames import shrink
from ..geometry.homography import (
    SiftHomography,
    area_ratio,
    fit_affine,
    fit_homography,
    fit_step,
    homography_flow,
    rescaled,
)
from ..geometry.images import to_gray
from ..geometry.splines import fit_bspline, fit_detail
from ..geometry.warp import compose
from .config import RefineConfig
from .context import PairContext, flow_distance
from .evidence import bound_outside


@dataclass(frozen=True)
class Start:
    """A hypothesis the refinement starts from: ``name`` ("network", "identity", "sift", "grown"), its
    homography ``H`` (None: none fitted, nothing is refined from it) and ``prior``, the flow the answer
    stays near where there is no support (the network's flow, zero for the identity)."""

    name: str
    H: np.ndarray | None
    prior: np.ndarray


@dataclass(frozen=True)
class Candidate:
    """A flow that competes in the selection: refined from start ``hypothesis`` on view ``images``
    ("normalised", "plain", "albedo"), or, ``plane`` True, the homography alone (refitted from that
    candidate, or SIFT's with ``images`` "homography"); ``aligned``: by direct alignment instead of DIS;
    ``polished``: an alignment polished by DIS (:func:`polish`); ``realigned``: the winner re-aligned
    (:func:`realign`)."""

    hypothesis: str
    images: str
    flow: np.ndarray
    plane: bool = False
    aligned: bool = False
    realigned: bool = False
    polished: bool = False

    @property
    def refitted(self) -> bool:
        """A refitted plane: its refined candidate simplified, not another explanation of the images."""
        return self.plane and self.images != "homography"

    @property
    def label(self) -> str:
        """The images in reports: ``images``, with ``-homography`` for a refitted plane."""
        label = f"{self.images}-homography" if self.refitted else self.images
        label = f"{label}-aligned" if self.aligned else label
        label = f"{label}-polished" if self.polished else label
        return f"{label}-realigned" if self.realigned else label

    @property
    def key(self) -> str:
        """``HYPOTHESIS/LABEL``: the candidate's name in :attr:`RefineInfo.scores` and the memo."""
        return f"{self.hypothesis}/{self.label}"


@dataclass(frozen=True)
class RefineInfo:
    """What :meth:`~projreg.refine.refiner.GeometricRefiner.predict_info` chose: ``hypothesis``
    ("network", "identity", "sift", "grown", "none" for a textureless pair or "skipped"), ``images``
    (:attr:`Candidate.label`: "normalised", "plain", "albedo", "homography" for a homography unrefined, or
    one of the first three with "-homography" for a refitted plane alone; "-aligned" when aligned directly,
    "-realigned" when re-aligned), the selection score of every candidate tried (keyed
    :attr:`Candidate.key`, texture-weighted mean local NCC in [-1, 1]), the per-pixel ``confidence``
    (float32 ``(H, W)`` in [0, 1]), ``evidence`` (the textured share of the frame) and ``stages``: the
    stages run, in order ("network", "more starts", "grown", "realigned", "bridge")."""

    hypothesis: str
    images: str
    scores: dict[str, float]
    confidence: np.ndarray
    evidence: float
    stages: tuple[str, ...] = ()


def network_start(config: RefineConfig, flow: np.ndarray) -> tuple[Start, bool]:
    """The network's start and whether its homography is well conditioned enough to answer with.

    The network's flow is fitted everywhere (it carries the network's hypothesis into flat regions;
    the refits keep to the textured pixels). A homography too bent to trust as an answer (strong lens
    distortion) still starts a refinement; an affine fit stands in when no homography is found. It reads
    the flow alone, so it runs while the pair's context is built."""
    fit, (h, w) = config.fit, flow.shape[:2]
    step = fit_step(h, w, fit.fit_points)  # the context's ``step``
    found = fit_homography(flow, step, fit.ransac_px, None, math.inf, fit.min_hull)
    usable = found is not None and area_ratio(found[0], h, w) <= fit.max_area_ratio
    found = found or fit_affine(flow, step, fit.ransac_px, fit.min_hull)
    return Start("network", None if found is None else found[0], flow), usable


def network_starts(config: RefineConfig, flow: np.ndarray) -> tuple[Start, list[Start], bool]:
    """The network's start (:func:`network_start`), the first stage's starts (it, when it has a
    homography, and the identity when that is not usable) and whether it is."""
    network, usable = network_start(config, flow)
    first = [network] if network.H is not None else []
    return network, first + ([] if usable else [identity_start(flow.shape[:2])]), usable


def identity_start(shape: tuple[int, ...]) -> Start:
    """The identity's start on a frame of ``shape[:2]``: the captured image as it is."""
    return Start("identity", np.eye(3), np.zeros((*shape[:2], 2), np.float32))


def sift_start(ctx: PairContext, sift: SiftHomography, projected: np.ndarray, captured: np.ndarray) -> Start | None:
    """SIFT + RANSAC's homography of the pair as a start, when it finds a proper, well conditioned one.

    SIFT runs on the pair, or on it shrunk to ``search.sift_side`` (the start only has to fall in the right basin:
    the refinement measures the rest) and its homography is brought back to the pair's pixels."""
    side = ctx.config.search.sift_side
    gray0, gray1 = to_gray(projected), to_gray(captured)
    if side is not None:
        gray0, gray1 = shrink(gray0, side), shrink(gray1, side)
    H, status, _ = sift(gray0, gray1)
    if status != "ok":
        return None
    H = rescaled(H, gray0.shape, ctx.shape)
    fit = ctx.config.fit
    flow = homography_flow(H, *ctx.shape)
    found = fit_homography(flow, ctx.refit_step, fit.ransac_px, None, fit.max_area_ratio, fit.min_hull)
    return None if found is None else Start("sift", found[0], flow)


def grown_start(ctx: PairContext, flow: np.ndarray, claimed: np.ndarray) -> Start | None:
    """The homography of ``flow`` on its ``claimed`` pixels as one more start, when that claim covers at
    least ``registered_above`` and less than ``grow_below`` of the frame and the homography fits.

    A candidate often verifies one part of the frame and misses the rest (its residual converged where
    its start was close); on a smooth surface the verified part's plane is a better start for the rest,
    and refined and checked like every other, it wins only where it explains the images better."""
    cfg = ctx.config
    share = float(claimed.mean())
    if not cfg.confidence.registered_above <= share < cfg.search.grow_below:
        return None
    fit = cfg.fit
    found = fit_homography(flow, ctx.step, fit.ransac_px, claimed, fit.max_area_ratio, fit.min_hull)
    return None if found is None else Start("grown", found[0], homography_flow(found[0], *ctx.shape))


def refine_start(ctx: PairContext, dis: cv2.DISOpticalFlow, start: Start, view: str) -> list[Candidate]:
    """The refinement of one start on one view, and the homography alone when it stands for it.

    The DIS residual is measured on the captured image warped back by the start's homography; the
    homography is refitted once (textured pixels, well conditioned) to model + residual and the residual
    measured again; the surface model (:func:`surface`) of that residual, composed on the refitted
    homography, is the candidate. The refitted homography alone competes too (``plane``) where it stays
    within ``plane_agree_px`` of the candidate on ``plane_agree_share`` of the textured pixels: on a
    planar scene the residual adds only DIS's noise."""
    cfg, (h, w) = ctx.config, ctx.shape
    base = homography_flow(start.H, h, w)
    full = compose(base, ctx.residual(dis, view, base))
    fit = cfg.fit
    found = fit_homography(full, ctx.step, fit.refit_px, ctx.textured, fit.max_area_ratio, fit.min_hull)
    if found is not None:
        base = homography_flow(found[0], h, w)
    flow = surface(ctx, view, base, ctx.residual(dis, view, base), start.prior)
    out = [Candidate(start.name, view, flow)]
    if found is not None:
        plane = bound_outside(base, start.prior, ctx.support, cfg.surface.free_px)
        if plane_agrees(ctx, plane, flow):
            out.append(Candidate(start.name, view, plane, plane=True))
    return out


def align_view(ctx: PairContext, start: Start, view: str) -> Candidate:
    """The direct alignment of one start on one view (:func:`aligned`), held within ``free_px`` of the
    start's prior outside the support. It starts from the start's homography, or, ``align.from_surface``
    on, from its smooth surface (:func:`smooth_rest` of the rest of its prior: a tracked frame's start is
    the last frame's answer, whose bend carries over)."""
    cfg, (h, w) = ctx.config, ctx.shape
    begin = homography_flow(start.H, h, w)
    if cfg.align.from_surface:
        begin = begin + smooth_rest(ctx, start.prior - begin)
    flow = bound_outside(aligned(ctx, view, begin), start.prior, ctx.support, cfg.surface.free_px)
    return Candidate(start.name, view, flow, aligned=True)


def polish_views(ctx: PairContext, view: str) -> tuple[str, ...]:
    """The views an alignment on ``view`` is polished on (:func:`polish`), of ``align.polish``: its own
    view where named, and for the plain images' alignment the albedo view (the same images with the
    wall's reflectance divided out) where named and ``images.albedo`` is on."""
    named = ctx.config.align.polish
    own = (view,) if view in named and view != "albedo" else ()
    return own + (("albedo",) if view == "plain" and "albedo" in named and ctx.config.images.albedo else ())


def polish(ctx: PairContext, dis: cv2.DISOpticalFlow, start: Start, alignment: Candidate, view: str) -> Candidate:
    """An ``alignment`` (:func:`align_view`) polished by the surface model of DIS's residual on ``view``:
    where the spline did not converge (e.g. a bend finer than its coarse grid), DIS measures what is
    left. On the albedo view the warped image is the alignment's own seen one."""
    residual = ctx.residual(dis, view, alignment.flow, alignment.key)
    flow = surface(ctx, view, alignment.flow, residual, start.prior)
    return Candidate(start.name, view, flow, aligned=True, polished=True)


def aligned_plane(ctx: PairContext, start: Start, alignment: Candidate) -> Candidate | None:
    """The homography refitted to an ``alignment``, held within ``free_px`` of the start's prior outside
    the support, as a candidate alone where it stands for it (:func:`plane_agrees`); else None."""
    cfg, (h, w) = ctx.config, ctx.shape
    fit = cfg.fit
    found = fit_homography(alignment.flow, ctx.refit_step, fit.refit_px, ctx.textured, fit.max_area_ratio, fit.min_hull)
    if found is None:
        return None
    plane = bound_outside(homography_flow(found[0], h, w), start.prior, ctx.support, cfg.surface.free_px)
    return replace(alignment, flow=plane, plane=True) if plane_agrees(ctx, plane, alignment.flow) else None


def realign(ctx: PairContext, best: Candidate, stop: Callable[[], bool] | None = None) -> Candidate | None:
    """The selected candidate aligned again directly (:func:`aligned`) from its smooth surface (its
    homography plus a P-spline of the rest on the fine grid, bend ``align.bend_start``), or None when the
    fit fails or the alignment moves the textured pixels farther than ``align.trust_px`` (at the
    ``plane_agree_share`` quantile) from it.

    A DIS-refined candidate carries DIS's noise under its spline (the spline is fitted to a residual
    measured patch by patch); the alignment measures the same surface model on every textured pixel at
    once. Kept within ``trust_px`` of an answer the search verified, it cannot move it to another basin.
    A homography that won alone gives way only to a re-alignment scoring ``plane_margin`` above it.
    ``stop``: as :func:`~projreg.geometry.align.align`'s (the search no longer wants the answer)."""
    cfg, (h, w) = ctx.config, ctx.shape
    fit = cfg.fit
    found = fit_homography(best.flow, ctx.refit_step, fit.refit_px, ctx.textured, fit.max_area_ratio, fit.min_hull)
    if found is None:
        return None
    trust = cfg.align.trust_px
    plane = homography_flow(found[0], h, w)
    flow = aligned(ctx, "normalised", plane + smooth_rest(ctx, best.flow - plane), stop, cfg.align.realign_coarse)
    near_data = ctx.near_data()  # as the detail level fades
    flow = best.flow + near_data[..., None] * (flow - best.flow)  # no change where the images carry no texture
    gap = flow_distance(flow, best.flow)[ctx.textured]
    if not gap.size or float(np.percentile(gap, 100 * cfg.selection.plane_agree_share)) > trust:
        return None
    again = replace(best, flow=flow, plane=False, realigned=True)
    if best.plane and ctx.score(again.key, flow) < ctx.score(best.key, best.flow) + cfg.selection.plane_margin:
        return None  # a plane that won alone gives way only by the margin it won by
    return again


def stays(ctx: PairContext, flow: np.ndarray, claimed: np.ndarray) -> float:
    """The share of ``claimed``'s textured pixels that a coarse-to-fine direct alignment of the whole frame,
    started from ``flow`` itself (:func:`aligned`, the normalised view), leaves within ``align.trust_px`` of
    it (in the pair's own pixels, ``ctx.scale``); 1.0 when nothing textured is claimed.

    A registration is a fixed point of that alignment: the images agree with it everywhere it holds, and
    the coarse levels, which see the whole frame, have nothing to move. A chance match of a few regions
    (a photo of another picture whose curves a flexible warp carried onto other curves) is a local
    optimum of the patch-wise refinement, which the frame's alignment leaves."""
    mask = claimed & ctx.textured
    if not mask.any():
        return 1.0
    again = aligned(ctx, "normalised", flow, None, True)
    return float((flow_distance(again, flow)[mask] <= ctx.config.align.trust_px / ctx.scale).mean())


def smooth_rest(ctx: PairContext, rest: np.ndarray) -> np.ndarray:
    """What a flow adds to its homography, ``rest`` ``(H, W, 2)``, as a P-spline on the fine grid with bend
    ``align.bend_start``: its surface without noise finer than that grid, an alignment's start."""
    sf, bend = ctx.config.surface, ctx.config.align.bend_start
    return fit_bspline(rest, ctx.evidence, sf.detail_grid, ctx.step, sf.robust_px, sf.ridge, sf.iterations, bend)


def aligned(
    ctx: PairContext, view: str, start: np.ndarray, stop: Callable[[], bool] | None = None, coarse: bool = True
) -> np.ndarray:
    """``start`` plus the coarse spline aligned coarse to fine on ``view``, then the fine one at full
    size (``align.detail``): :func:`~projreg.geometry.align.align` (``stop``: its). ``coarse`` off (with
    ``align.detail``): the fine spline alone, for a start already within about a pixel."""
    al, sf = ctx.config.align, ctx.config.surface
    levels = ctx.pyramid(view)
    steps = dict(zip(al.levels, al.steps, strict=True))
    rest = (al.ridge, al.max_step, al.tolerance, stop, al.step_on_texture, al.cauchy)  # align's other arguments
    flow = start
    if coarse or not al.detail:
        flow = align(levels, flow, sf.grid, steps, al.bend, *rest)
    if al.detail:
        last = (al.narrow_steps, al.narrow_cauchy)
        flow = align(levels, flow, sf.detail_grid, {1: al.detail_steps}, al.detail_bend, *rest, last)
    return flow


def surface(ctx: PairContext, view: str, base: np.ndarray, residual: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """``base`` composed with the coarse spline of ``residual`` (and the cross-validated fine level where
    it wins, :func:`~projreg.geometry.splines.fit_detail`), held within ``free_px`` of ``prior`` outside
    the support."""
    sf, weight = ctx.config.surface, ctx.weight(view)
    smooth = fit_bspline(residual, weight, sf.grid, ctx.step, sf.robust_px, sf.ridge, sf.iterations)
    if sf.detail:
        detail, _ = fit_detail(
            residual - smooth,
            weight,
            sf.detail_grid,
            sf.detail_bends,
            ctx.step,
            sf.robust_px,
            block=sf.detail_block,
            gain=sf.detail_gain,
            ridge=sf.ridge,
            iterations=sf.iterations,
            fade=sf.detail_fade,
            near_data=lambda: ctx.near_data(view),
        )
        smooth = smooth + detail
    return bound_outside(compose(base, smooth), prior, ctx.support, sf.free_px)


def plane_agrees(ctx: PairContext, plane: np.ndarray, flow: np.ndarray) -> bool:
    """Whether a homography's flow stays within ``plane_agree_px`` of the refined ``flow`` it was
    simplified from on ``plane_agree_share`` of the textured pixels: only then is it the same
    explanation of the images with less noise."""
    sel = ctx.config.selection
    gap = flow_distance(plane, flow)[ctx.textured]
    return bool(gap.size) and float(np.percentile(gap, 100 * sel.plane_agree_share)) <= sel.plane_agree_px


def sift_plane(start: Start) -> Candidate:
    """SIFT's homography as it is, which no residual refines."""
    return Candidate(start.name, "homography", start.prior, plane=True)
