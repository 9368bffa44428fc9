"""The geometric refinement's settings: :class:`RefineConfig`, in sections (images, fit, align,
surface, search, selection, confidence), and the three qualities of :data:`QUALITIES` (``fast``, ``balanced``,
``accurate``, the default) that ``predict --quality`` and ``bench --quality`` name.

Every number the refinement uses is a field here, with one meaning each; a stage that can be left out
has an on/off flag (no special values). docs/model.md explains each stage and the qualities' figures
are in docs/results.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ..errors import ProjregError

MIN_SIDE = 32  # below this DIS has no pyramid to work with: the flow is returned unchanged
VIEWS = ("normalised", "plain", "albedo")  # the gray images a residual is measured on (PairContext.views)


@dataclass(frozen=True)
class ImagesConfig:
    """The views of the pair the residuals are measured on and the evidence read from them."""

    max_side: int | None = None  # refine the pair shrunk to this longer side (None: its own size) ...
    verify_full: bool = False  # ... and verify the answer at the pair's own size (else: its confidence resized) ...
    verify_full_below: float = 0.0  # ... or only where it claims less than this share of the visible texture
    contrast_sigma: float = 8.0  # Gaussian window (px) of the local contrast normalisation
    shrunk_sigma: float = 3.5  # local statistics (contrast, NCC) of a window sigma >= twice this (px) are
    # taken on the images shrunk sigma // this times (geometry.images.gaussian)
    plain: bool = True  # also measure residuals on the gray images without normalisation
    albedo: bool = True  # also measure them with the wall's reflectance divided out (divide_albedo)
    albedo_window: int = 31  # median window (odd, px) of the reflectance estimate
    texture_floor: float = 256.0  # gradient energy that counts as texture however flat the frame (64 g^2)
    texture_sigma: float = 3.0  # Gaussian window (px) of the gradient energy
    textured_at: float = 0.5  # texture weight from which a pixel counts as textured
    textureless_below: float = 0.01  # a pair whose textured share is below this is not registered


@dataclass(frozen=True)
class FitConfig:
    """The projective fits: the starts' homographies and their refits."""

    ransac_px: float = 2.0  # inlier threshold of the homography fitted to a start's flow
    refit_px: float = 1.0  # inlier threshold of the homography refitted to model + residual
    fit_points: int = 12288  # grid correspondences (about) of a fit of a noisy flow (network, DIS) ...
    refit_points: int = 3072  # ... and of a smooth one (an alignment, the winner, SIFT's homography)
    max_area_ratio: float = 6.0  # a fit whose local area scale varies more over the frame is refused
    min_hull: float = 0.02  # a fit whose inliers' hull covers less of the frame is refused


@dataclass(frozen=True)
class AlignConfig:
    """Direct photometric alignment of the surface model to the images (:mod:`~projreg.geometry.align`):
    the re-alignment of the selected answer, and, ``direct`` on, the first stage's estimator."""

    realign: bool = True  # align the selected answer again from its homography (DIS's noise left out) ...
    trust_px: float = 1.0  # ... kept where it moves the textured pixels at most this far (selection.plane_agree_share)
    bend_start: float = 0.3  # ... starting from its homography + a P-spline of the rest with this bend (fine grid)
    realign_coarse: bool = False  # ... aligning the coarse grid over the pyramid first (off: the fine grid alone,
    # at full size: the start is within a pixel; without align.detail the coarse grid is aligned either way)
    direct: bool = False  # the first stage aligns the network's start directly, no DIS; the DIS search of
    # every start and view follows only when it claims less than search.escalate_below of the texture
    views: tuple[str, ...] = ("normalised",)  # the views the first stage aligns on, with direct ...
    polish: tuple[str, ...] = ("normalised", "albedo")  # ... and polished by DIS's residual on these views:
    # "normalised" or "plain" that view's alignment, "albedo" the plain one's with the wall's reflectance
    # divided out (a painted or brick wall moves with neither image); () none
    from_surface: bool = False  # ... each from its start's smooth surface (homography + bend_start P-spline
    # of the rest of its flow) instead of its homography: a tracked frame's, whose start is the last answer
    levels: tuple[int, ...] = (4, 2, 1)  # pyramid factors, coarsest first
    steps: tuple[int, ...] = (6, 4, 3)  # Gauss-Newton steps at each level, at most (align.tolerance)
    max_step: float = 1.0  # the most one step moves a control value, in pixels of its level ...
    step_on_texture: bool = False  # ... or, on, a textured pixel (a value over a flat region shortens no step)
    cauchy: float = 1.0  # the robust weights' Cauchy scale, in standard deviations of the residuals, ...
    narrow_steps: int = 0  # ... except on the fine grid's last this many steps (align.detail), at ...
    narrow_cauchy: float = 1.0  # ... this scale: a wide Cauchy converges in fewer steps, a narrow one lets go
    # of the occluders and reflectance edges a wide one let pull the surface
    tolerance: float = 0.02  # a level's steps stop once one moves no control value farther (px of the level)
    bend: float = 0.01  # second-difference penalty of the coarse grid (surface.grid), relative
    ridge: float = 1e-4  # pull of every control value towards 0, relative
    detail: bool = True  # then align the fine grid (surface.detail_grid) at full size ...
    detail_steps: int = 6  # ... with at most this many steps (align.tolerance stops it earlier)
    detail_bend: float = 0.1  # ... and this second-difference penalty, relative


@dataclass(frozen=True)
class SurfaceConfig:
    """The smooth surface model fitted to the residual (coarse B-spline, optional fine P-spline)."""

    grid: tuple[int, int] = (6, 5)  # coarse control points (x, y)
    robust_px: float = 1.0  # Cauchy scale of the reweighting, px
    ridge: float = 1e-3  # Tikhonov weight keeping control points without texture at zero residual
    iterations: int = 3  # weighted solves (the first without residual weights)
    detail: bool = True  # add the fine P-spline where cross-validation says the residual carries detail
    detail_grid: tuple[int, int] = (14, 11)  # its control points (x, y)
    detail_bends: tuple[float, ...] = (0.3, 3.0, 30.0)  # its second-difference penalties tried
    detail_block: int = 32  # checkerboard block (px) of its two-fold cross-validation
    detail_gain: float = 0.05  # held-out loss it must save, as a share of leaving the remainder alone
    detail_fade: tuple[float, float] = (0.05, 0.3)  # texture density ramp where the detail fades out
    support_margin: float = 0.1  # pixels farther than this share of the longer side from texture have no support
    free_px: float = 16.0  # outside the support the answer stays within this distance of its start


@dataclass(frozen=True)
class SearchConfig:
    """Which starts the refinement tries, and when it spends more."""

    identity: bool = True  # also start from the identity (always when the network's flow has no homography)
    sift: bool = True  # also start from a SIFT + RANSAC homography of the pair
    sift_side: int | None = None  # ... found on the pair shrunk to this longer side (None: its own size)
    first_views: tuple[str, ...] = ("normalised", "plain", "albedo")  # views the first stage refines on
    escalate_below: float = 1.0  # the second stage (the identity and SIFT starts, the views not in
    # first_views) runs only when the first stage's answer claims less than this share of the textured
    # pixels (1.0: always, every start and view in one stage)
    settle_at: float = 1.0  # with align.direct, a first stage claiming at least this share of the visible
    # texture is final: no growth, and no re-alignment unless its winner was polished
    keep_direct_at: float = 1.0  # with align.direct, an escalation keeps the first stage's aligned candidates as
    # rivals of DIS's where they claimed at least this share of the visible texture (else they are dropped)
    grow: bool = True  # a partial answer's verified plane starts one more hypothesis
    grow_below: float = 0.8  # ... when the answer claims less than this share of the frame
    workers: int = 2  # threads refining a stage's candidates side by side (OpenCV and numpy release the GIL)


@dataclass(frozen=True)
class SelectionConfig:
    """How candidates are scored and one is chosen."""

    ncc_sigma: float = 7.0  # Gaussian window (px) of the local NCC that scores a candidate
    plane_margin: float = 0.005  # a homography alone wins when it scores within this of the best
    plane_agree_px: float = 2.0  # ... and stays within this distance of its candidate
    plane_agree_share: float = 0.9  # ... on this share of the textured pixels


@dataclass(frozen=True)
class ConfidenceConfig:
    """The per-pixel checks, their pass marks, and the verdict."""

    ncc_fail: float = 0.3  # local NCC at or below which a pixel fails the photometric check
    ncc_pass: float = 0.6  # ... and at or above which it passes
    residual_pass_px: float = 2.0  # forward-backward residual (px) at or below which a pixel passes
    residual_fail_px: float = 4.0  # ... and at or above which it fails
    spread_pass_px: float = 2.0  # distance to an equally good rival (px) at or below which a pixel passes
    spread_fail_px: float = 4.0  # ... and at or above which it fails
    rival_margin: float = 0.05  # a candidate scoring within this of the winner is a rival
    radius: float = 0.03  # fine neighbourhood (share of the longer side) the pass marks are averaged over
    shrunk_sigma: float = 6.0  # a neighbourhood of sigma >= twice this (px) is averaged on a grid shrunk to keep it
    sparse: float = 0.05  # texture density at which the fine neighbourhood starts to count
    coarse_sparse: float = 0.1  # ... the coarse one (twice the radius) and the bridge's (four times)
    dense: float = 0.2  # texture density at which a neighbourhood counts fully
    span_radii: float = 4.0  # the passing texture within this many radii of a pixel (Gaussian sigma) ...
    span_fail: float = 0.03  # ... fixes no position along its edges when the smaller eigenvalue of its structure
    # tensor is at most this share of the larger (edges of one direction: a flow may slide along them) ...
    span_pass: float = 0.06  # ... and fixes it in both directions from this share on
    registered_above: float = 0.01  # a pair whose claimed share is below this is not registered ...
    registered_windows: float = 6.0  # ... nor one whose claim covers fewer NCC windows than this (0: none; area
    # pi (2 selection.ncc_sigma)^2 each): photos of another picture pass the checks by chance on up to 4 of them
    periodic: bool = True  # refuse pixels where the projected image repeats itself
    periodic_peak: float = 0.85  # autocorrelation peak (64 px windows) that marks a repeat
    coarse_peak: float = 0.93  # ... in the larger windows
    periodic_tiles: tuple[int, ...] = (64, 128, 256)  # the periodicity test's windows (px), finest first
    periodic_lobe: float = 0.3  # autocorrelation level that bounds its central lobe (an edge's ridge)
    periodic_overlap: float = 0.25  # shifts whose windows overlap less than this share of a window say nothing
    repeating_share: float = 0.5  # an unverified pair whose texture repeats this much is called a repeating pattern
    bridge: bool = True  # a registered answer also claims wide flat gaps where two models agree
    bridge_px: float = 1.0  # ... within this distance of its claimed pixels' homography
    mirror_side: int | None = 256  # a registered pair's images, shrunk to this side, are checked for a mirrored
    # capture (:mod:`~projreg.refine.handedness`; None: not checked) ...
    mirror_inliers: int = 30  # ... which is mirrored when at least this many mirrored SIFT matches agree ...
    mirror_ratio: float = 3.0  # ... and this many times as many as the direct matches do; from this many mirrored
    mirror_scored: int = 10  # matches (same ratio), mirrored when their homography scores above the answer
    confirm_below: float = 0.5  # a registered claim under this share of the frame is aligned again from itself ...
    confirm_share: float = 0.5  # ... and stands when this share of its claimed textured pixels stays (align.trust_px)
    pin: bool = True  # a claimed pixel needs structure that fixes a position in two directions within one
    # check window (a corner, a blob, not a curve alone) nearby: near as the answer's bending asks ...
    pin_fail: float = 0.1  # ... a window's structure tensor, eigenvalue ratio at or below which it fixes none ...
    pin_pass: float = 0.2  # ... and at or above which it fixes a position alone (selection.ncc_sigma windows)
    pin_share: float = 0.02  # ... such windows' share of the passing texture within the reach, from which it holds
    pin_bend_px: float = 1.0  # the reach: the distance over which the answer leaves its chord by this (px), one
    # radius to span_radii radii


@dataclass(frozen=True)
class RefineConfig:
    """Parameters of :class:`~projreg.refine.refiner.GeometricRefiner`, by section (each field has its
    one-line meaning in its section's class; defaults chosen on the validation split, docs/model.md)."""

    images: ImagesConfig = field(default_factory=ImagesConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    align: AlignConfig = field(default_factory=AlignConfig)
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    search: SearchConfig = field(default_factory=SearchConfig)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)

    def with_sections(self, **sections: dict) -> RefineConfig:
        """This configuration with some fields of its sections replaced, e.g.
        ``ACCURATE.with_sections(search={"sift": False}, surface={"detail": False})``."""
        return replace(self, **{name: replace(getattr(self, name), **fields) for name, fields in sections.items()})

    def __post_init__(self) -> None:
        im, fit, sf, se = self.images, self.fit, self.surface, self.search
        al = self.align
        if len(al.levels) != len(al.steps) or not al.levels or min(al.levels) < 1 or al.levels[-1] != 1:
            raise ProjregError(f"refine align.levels must end at 1, one per align.steps, got {al.levels}, {al.steps}")
        if min(sf.grid) < 4 or min(sf.detail_grid) < 4:
            raise ProjregError(f"refine grids need at least 4 x 4 control points, got {sf.grid}, {sf.detail_grid}")
        positive = {
            "fit.ransac_px": fit.ransac_px,
            "fit.refit_px": fit.refit_px,
            "surface.robust_px": sf.robust_px,
            "selection.ncc_sigma": self.selection.ncc_sigma,
            "images.contrast_sigma": im.contrast_sigma,
            "images.shrunk_sigma": im.shrunk_sigma,
            "fit.fit_points": fit.fit_points,
            "fit.refit_points": fit.refit_points,
            "confidence.radius": self.confidence.radius,
            "confidence.shrunk_sigma": self.confidence.shrunk_sigma,
            "align.trust_px": al.trust_px,
            "align.max_step": al.max_step,
            "align.cauchy": al.cauchy,
            "align.narrow_cauchy": al.narrow_cauchy,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ProjregError(f"refine {name} must be > 0, got {value}")
        if not al.tolerance >= 0:
            raise ProjregError(f"refine align.tolerance must be >= 0, got {al.tolerance}")
        if not 0 <= al.narrow_steps <= al.detail_steps:
            raise ProjregError(
                f"refine align.narrow_steps must be in [0, align.detail_steps = {al.detail_steps}], "
                f"got {al.narrow_steps}"
            )
        for name, views in (
            ("align.views", al.views),
            ("align.polish", al.polish),
            ("search.first_views", se.first_views),
        ):
            if unknown := set(views) - set(VIEWS):
                raise ProjregError(f"refine {name} names views {', '.join(VIEWS)}; got {sorted(unknown)}")
        off = [v for v in al.views if v in ("plain", "albedo") and not getattr(im, v)]
        if al.direct and (off or not al.views):
            raise ProjregError(
                f"refine align.views must name one view or more, each one the images section measures (plain "
                f"needs images.plain, albedo images.albedo); got {list(al.views)}"
            )
        if im.max_side is not None and im.max_side < MIN_SIDE:
            raise ProjregError(f"refine images.max_side must be >= {MIN_SIDE}, got {im.max_side}")
        if im.albedo and (im.albedo_window < 3 or im.albedo_window % 2 == 0):
            raise ProjregError(f"refine images.albedo_window must be an odd number >= 3, got {im.albedo_window}")
        if not 0 <= im.verify_full_below <= 1:
            raise ProjregError(f"refine images.verify_full_below must be in [0, 1], got {im.verify_full_below}")
        for name in ("grow_below", "escalate_below", "settle_at", "keep_direct_at"):
            if not 0 <= getattr(se, name) <= 1:
                raise ProjregError(f"refine search.{name} must be in [0, 1], got {getattr(se, name)}")
        if se.sift_side is not None and se.sift_side < MIN_SIDE:
            raise ProjregError(f"refine search.sift_side must be >= {MIN_SIDE} or None, got {se.sift_side}")
        if se.workers < 1:
            raise ProjregError(f"refine search.workers must be >= 1, got {se.workers}")
        if not self.confidence.registered_windows >= 0:
            raise ProjregError(
                f"refine confidence.registered_windows must be >= 0, got {self.confidence.registered_windows}"
            )
        co = self.confidence
        if co.mirror_side is not None and co.mirror_side < MIN_SIDE:
            raise ProjregError(f"refine confidence.mirror_side must be >= {MIN_SIDE} or None, got {co.mirror_side}")
        if min(co.mirror_inliers, co.mirror_scored) < 4 or not co.mirror_ratio >= 1:
            raise ProjregError(
                "refine confidence.mirror_inliers and mirror_scored must be >= 4 (a homography's points) and "
                f"mirror_ratio >= 1, got {co.mirror_inliers}, {co.mirror_scored}, {co.mirror_ratio}"
            )
        if not (0 <= co.pin_fail < co.pin_pass <= 1 and 0 < co.pin_share <= 1 and co.pin_bend_px > 0):
            raise ProjregError(
                "refine confidence.pin_fail < pin_pass must lie in 0..1, pin_share in (0, 1] and pin_bend_px > 0, got "
                f"{co.pin_fail}, {co.pin_pass}, {co.pin_share}, {co.pin_bend_px}"
            )
        if not (0 <= co.confirm_below <= 1 and 0 <= co.confirm_share <= 1):
            raise ProjregError(
                f"refine confidence.confirm_below and confirm_share must be in 0..1, got {co.confirm_below}, "
                f"{co.confirm_share}"
            )
        for name in ("plane_margin", "plane_agree_px"):
            if not getattr(self.selection, name) >= 0:
                raise ProjregError(f"refine selection.{name} must be >= 0, got {getattr(self.selection, name)}")


@dataclass(frozen=True)
class Quality:
    """One setting of the quality dial: where the network runs and how the refinement searches.

    ``network_side``: the longer side the network sees at most (the pair is shrunk for it and its flow
    brought back); ``refine``: the refinement's configuration; ``escalate_side``: where the refinement's
    first stage leaves the frame unverified, the network runs again at up to this side and the second
    stage starts from that flow (None: the first flow serves)."""

    name: str
    network_side: int
    refine: RefineConfig
    about: str
    escalate_side: int | None = None

    def finer_side(self, max_side: int | None = None) -> int | None:
        """The escalation's network side under a user's ``--max-side`` (None: no cap): None when it would
        see no more than the first pass."""
        cap = self.escalate_side if max_side is None else max_side
        side = None if self.escalate_side is None else min(self.escalate_side, cap)
        return side if side is not None and side > min(self.network_side, cap) else None


# ``balanced`` (the default): the network at 256 px, its start aligned directly to the normalised and
# the plain images, the normalised alignment polished by DIS on its view and the plain one on the albedo
# view (each alignment's steps stop once they no longer move it, ``align.tolerance``; their robust weights
# wide, 2.385 standard deviations, which converges in fewer steps, but for the fine grid's last three steps
# at one, which let go of the occluders and reflectance edges the wide ones let pull it); where that verifies
# less than half of the visible texture, the network again at up to 512 px and ``accurate``'s search from
# it (a first stage that verifies more has found the frame's basin: its verified plane grows over the
# rest, and it is re-aligned, below 85 %); a pair larger than 512 px is searched shrunk to 512 px and
# its answer verified at its own size (the estimator's cost grows with the pixels, the network's with
# their square).
# ``accurate``: ``balanced``'s first stage, then always the network again at up to 1024 px and every start
# on every view from it, the first stage's aligned answers kept beside DIS's where they verified what would
# have stopped ``balanced`` (half the visible texture), the winner re-aligned directly, every pair searched
# at its own size (docs/history/2026-12-05-accurate-and-fast-claims.md).
# ``fast``: the network's start aligned directly to the normalised images at 256 px (no DIS),
# the fit's pixel parameters halved, no detail level, albedo view or bridge, and the residual's pass marks
# halved (1 px passes, 2 px fails: its smaller search leaves pixels 2-3 px off that pass the default's
# marks; docs/history/2026-12-05-honest-claims.md); an answer claiming under half the visible texture is
# verified again at the pair's own size (a small claim's evidence, checked at 256 px, let pixels 1.5-1.7 px off pass).
# Their figures: docs/results.md.
SEARCH = RefineConfig()  # every start on every view in one stage (the settings' defaults)
BALANCED = SEARCH.with_sections(
    images={"max_side": 512, "verify_full": True},
    align={
        "direct": True,
        "views": ("normalised", "plain"),
        "steps": (6, 4, 1),
        "detail_steps": 6,
        "cauchy": 2.385,
        "narrow_steps": 3,
    },
    search={"escalate_below": 0.5, "settle_at": 0.85},
)
FAST = RefineConfig(
    images=ImagesConfig(max_side=256, verify_full_below=0.5, plain=False, albedo=False),
    align=AlignConfig(direct=True, realign=False, detail=False, polish=()),
    fit=FitConfig(ransac_px=1.0, refit_px=0.5, fit_points=3072),
    surface=SurfaceConfig(robust_px=0.5, free_px=8.0, detail=False),
    search=SearchConfig(identity=False, sift=False, escalate_below=0.0),
    selection=SelectionConfig(ncc_sigma=3.5),
    confidence=ConfidenceConfig(bridge=False, residual_pass_px=1.0, residual_fail_px=2.0),
)
ACCURATE = BALANCED.with_sections(
    images={"max_side": None, "verify_full": False},
    search={"escalate_below": 1.0, "settle_at": 1.0, "keep_direct_at": BALANCED.search.escalate_below},
)
QUALITIES = {
    q.name: q
    for q in (
        Quality("fast", 256, FAST, "the network at 256 px, its start aligned to the images at 256 px"),
        Quality(
            "balanced",
            256,
            BALANCED,
            "the network at 256 px aligned directly; where that leaves the frame unverified, accurate's search; "
            "searched at up to 512 px, verified at the pair's size",
            escalate_side=512,
        ),
        Quality(
            "accurate",
            256,
            ACCURATE,
            "balanced's first stage, then the network at up to 1024 px and every start on every view beside it, "
            "re-aligned",
            escalate_side=1024,
        ),
    )
}
DEFAULT_QUALITY = "balanced"


def quality(name: str) -> Quality:
    """The quality setting called ``name``.

    Raises:
        ProjregError: naming ``--quality`` when there is no such setting.
    """
    if name not in QUALITIES:
        raise ProjregError(f"--quality {name!r}: expected one of {', '.join(QUALITIES)}")
    return QUALITIES[name]
