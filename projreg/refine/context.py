"""What the refinement knows about one pair, built once: its views, its texture evidence and support, and
the cache of every candidate's check maps (:class:`PairContext`).

Convention: gray images ``(H, W)`` on the projected grid; flows float32 ``(H, W, 2)``, forward,
projected -> captured, pixels.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from projsynth.utils.jit import jit

from ..geometry.align import Level, pyramid
from ..geometry.homography import fit_step
from ..geometry.images import (
    LocalStats,
    divide_albedo,
    near,
    normalize_contrast,
    texture_weight,
    to_gray,
    weighted_mean,
)
from ..geometry.splines import near_data_ramp
from ..geometry.warp import compose, lands_inside, warp_back
from ..prediction import CONFIDENT
from .config import RefineConfig
from .handedness import Features

DisFlows = Callable[[list[tuple[np.ndarray, np.ndarray]]], list[np.ndarray]]  # DIS's flow of each image pair


def flow_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel distance (px) between two float32 flows, float32 ``(H, W)``."""
    return _flow_distance(a, b)


@jit
def _flow_distance(a, b):  # pragma: no cover - numba
    h, w = a.shape[:2]
    out = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            out[y, x] = math.hypot(a[y, x, 0] - b[y, x, 0], a[y, x, 1] - b[y, x, 1])
    return out


@dataclass
class Projected:
    """What the refinement reads from the projected image alone (:meth:`build`), shared by every pair
    with that image: a tracked sequence, or a folder of captures of one picture.

    ``image``: the uint8 RGB image it was built from (a copy, to recognise it: :meth:`matches`);
    ``plain``/``normalised``: its gray image without and with local contrast normalisation; ``evidence``,
    ``share``, ``textured``, ``support``, ``step``, ``refit_step``: as :class:`PairContext`'s;
    ``reference``: the local statistics the NCC maps compare with; ``tensor``: the normalised image's
    gradient products ``(gx^2, gx gy, gy^2)``, float32 ``(H, W, 3)``, which say along which directions its
    texture fixes a position (:func:`~projreg.refine.confidence.spanned`); ``weights``: each view's texture
    weight, by view, filled as asked, and ``near`` the fine spline's data ramp of each
    (:meth:`PairContext.near_data`); ``repeats``: where the image repeats itself (None until the
    refinement has measured it); ``features``: its SIFT features for the handedness check (None until
    measured, :mod:`~projreg.refine.handedness`); ``corners``: how well each check window of it fixes a
    position alone (the eigenvalue ratio of ``tensor`` over one window; None until asked,
    :func:`~projreg.refine.verify.pinned`).
    """

    image: np.ndarray
    plain: np.ndarray
    normalised: np.ndarray
    evidence: np.ndarray
    share: float
    textured: np.ndarray
    support: np.ndarray
    step: int
    refit_step: int
    reference: LocalStats
    tensor: np.ndarray
    weights: dict[str, np.ndarray] = field(default_factory=dict)
    near: dict[str, np.ndarray] = field(default_factory=dict)
    repeats: np.ndarray | None = None
    features: Features | None = None
    corners: np.ndarray | None = None

    @classmethod
    def build(cls, projected: np.ndarray, config: RefineConfig) -> Projected:
        """The projected side of a uint8 RGB ``(H, W, 3)`` image under ``config``."""
        im = config.images
        plain = to_gray(projected)
        normalised = normalize_contrast(plain, im.contrast_sigma, im.shrunk_sigma)
        evidence = texture_weight(plain, im.texture_floor, im.texture_sigma)
        textured = evidence >= im.textured_at
        h, w = plain.shape
        return cls(
            projected.copy(),
            plain,
            normalised,
            evidence,
            float(textured.mean()),
            textured,
            near(textured, config.surface.support_margin * max(h, w)),
            fit_step(h, w, config.fit.fit_points),
            fit_step(h, w, config.fit.refit_points),
            LocalStats(normalised, config.selection.ncc_sigma, im.shrunk_sigma),
            gradient_products(normalised),
        )

    def matches(self, projected: np.ndarray) -> bool:
        """Whether ``projected`` is the image this was built from."""
        return self.image.shape == projected.shape and np.array_equal(self.image, projected)


@dataclass
class PairContext:
    """One pair as every stage reads it (:meth:`build`).

    ``side``: what the projected image alone gives (:class:`Projected`, shared between pairs);
    ``plain``/``normalised``: the gray images ``(projected, captured)`` without and with local contrast
    normalisation; ``evidence``: the projected image's texture weight in [0, 1] (absolute floor);
    ``share``: its textured share of the frame; ``textured``/``support``: bool maps of the textured
    pixels and of those near enough to texture to be measured; ``step``: the fits' grid step, ``refit_step``
    the refits' (``fit.refit_points``);
    ``pyramids``: each view's pyramid for the direct alignment; ``memo``: each candidate's check maps,
    by key (scored once, read again by the confidence); ``scale``: the pair's own pixels per pixel of
    these images, where they are the pair shrunk and its verdict is read here (the checks' distances are
    the user's pixels: :func:`~projreg.refine.verify.confidence`).
    """

    config: RefineConfig
    side: Projected
    plain: tuple[np.ndarray, np.ndarray]
    normalised: tuple[np.ndarray, np.ndarray]
    scale: float = 1.0
    pyramids: dict[str, dict[int, Level]] = field(default_factory=dict)
    memo: dict[str, np.ndarray] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @classmethod
    def build(
        cls,
        projected: np.ndarray,
        captured: np.ndarray,
        config: RefineConfig,
        side: Projected | None = None,
        scale: float = 1.0,
    ) -> PairContext:
        """The context of a pair of uint8 RGB ``(H, W, 3)`` images; ``side``: the projected image's, when
        already built (:meth:`Projected.matches`); ``scale``: as the class docstring."""
        side = side or Projected.build(projected, config)
        gray = to_gray(captured)
        normalised = normalize_contrast(gray, config.images.contrast_sigma, config.images.shrunk_sigma)
        return cls(config, side, (side.plain, gray), (side.normalised, normalised), scale=scale)

    @property
    def evidence(self) -> np.ndarray:
        return self.side.evidence

    @property
    def share(self) -> float:
        return self.side.share

    @property
    def textured(self) -> np.ndarray:
        return self.side.textured

    @property
    def support(self) -> np.ndarray:
        return self.side.support

    @property
    def step(self) -> int:
        return self.side.step

    @property
    def refit_step(self) -> int:
        return self.side.refit_step

    @property
    def shape(self) -> tuple[int, int]:
        return self.plain[0].shape

    def views(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The views residuals are measured on, in the order candidates are tried: normalised, then plain
        and albedo when configured (albedo reads the plain images and divides the reflectance out)."""
        im = self.config.images
        out = {"normalised": self.normalised}
        if im.plain:
            out["plain"] = self.plain
        if im.albedo:
            out["albedo"] = self.plain
        return out

    def near_data(self, view: str | None = None) -> np.ndarray:
        """How much data the fine spline has near each pixel on ``view``'s texture weight (None: the
        evidence): :func:`~projreg.geometry.splines.near_data_ramp`, computed once per projected image."""
        key = view or "evidence"
        with self._lock:
            if key not in self.side.near:
                sf = self.config.surface
                weight = self.evidence if view is None else self.weight(view)
                self.side.near[key] = near_data_ramp(weight, sf.detail_grid, sf.detail_fade)
        return self.side.near[key]

    def weight(self, view: str) -> np.ndarray:
        """The surface fit's texture weight on ``view``: relative on the normalised images, with the
        absolute floor on the others."""
        weights = self.side.weights
        if view not in weights:
            floor = 0.0 if view == "normalised" else self.config.images.texture_floor
            gray = self.normalised[0] if view == "normalised" else self.plain[0]
            weights[view] = texture_weight(gray, floor, self.config.images.texture_sigma)
        return weights[view]

    def pyramid(self, view: str) -> dict[int, Level]:
        """``view``'s image pyramid for the direct alignment (``align.levels``), built once."""
        with self._lock:
            if view not in self.pyramids:
                gray0, gray1 = self.views()[view] if view != "albedo" else self.plain
                self.pyramids[view] = pyramid(gray0, gray1, self.evidence, self.config.align.levels)
        return self.pyramids[view]

    def residual(self, dis: cv2.DISOpticalFlow, view: str, base: np.ndarray, key: str | None = None) -> np.ndarray:
        """DIS flow from the projected image to the captured one warped back by ``base``, on ``view``;
        on the albedo view the warped image is divided by the wall's reflectance first and both are
        normalised: what :meth:`seen` shows of ``base``, kept under ``key`` when given (the candidate
        ``base`` is)."""
        if view == "albedo":
            return dis.calc(self.normalised[0], self.seen(key, base) if key else self._seen(base), None)
        gray0, gray1 = self.views()[view]
        return dis.calc(gray0, warp_back(gray1, base), None)

    def seen(self, key: str, flow: np.ndarray) -> np.ndarray:
        """The captured image warped back by ``flow`` as the selection and the checks compare it with the
        normalised projected image: normalised, the wall's reflectance divided out first with ``albedo``;
        kept under ``key``."""
        memo_key = f"seen:{key}"
        if memo_key not in self.memo:
            self.memo[memo_key] = self._seen(flow)
        return self.memo[memo_key]

    def _seen(self, flow: np.ndarray) -> np.ndarray:
        im = self.config.images
        if not im.albedo:
            return warp_back(self.normalised[1], flow)
        return normalize_contrast(
            self._divide_albedo(warp_back(self.plain[1], flow)), im.contrast_sigma, im.shrunk_sigma
        )

    def _divide_albedo(self, warped: np.ndarray) -> np.ndarray:
        return divide_albedo(self.plain[0], warped, self.config.images.albedo_window)

    def ncc(self, key: str, flow: np.ndarray) -> np.ndarray:
        """Local NCC map ``(H, W)`` between the normalised projected image and what :meth:`seen` shows of
        ``flow``, kept under ``key``."""
        memo_key = f"ncc:{key}"
        if memo_key not in self.memo:
            self.memo[memo_key] = self.side.reference.ncc(self.seen(key, flow))
        return self.memo[memo_key]

    def score(self, key: str, flow: np.ndarray) -> float:
        """The selection score: the texture-weighted mean of :meth:`ncc`, in [-1, 1]."""
        return weighted_mean(self.ncc(key, flow), self.evidence)

    def claimed_share(self, conf: np.ndarray, flow: np.ndarray) -> float:
        """The share of the textured pixels that ``flow`` keeps in the captured frame which an answer of
        confidence ``conf`` claims (the pixels it sends out of the frame cannot be verified)."""
        seen = self.textured & lands_inside(flow, self.shape)
        return float((conf[seen] >= CONFIDENT).mean()) if seen.any() else 0.0

    def round_trip(self, dis: DisFlows, key: str, flow: np.ndarray) -> np.ndarray:
        """Forward-backward residual (px, ``(H, W)``) between the projected image and the captured one
        warped back by ``flow``: what DIS still finds to move either way round; ~0 where the flow holds.
        ``dis``: DIS's flows of a list of image pairs (both ways at once where it has two threads)."""
        memo_key = f"residual:{key}"
        if memo_key not in self.memo:
            gray0, warped = self.normalised[0], self.seen(key, flow)
            fwd, bwd = dis([(gray0, warped), (warped, gray0)])
            zero = np.zeros_like(fwd)
            self.memo[memo_key] = np.maximum(flow_distance(fwd, zero), flow_distance(compose(bwd, fwd), zero))
        return self.memo[memo_key]


def gradient_products(gray: np.ndarray) -> np.ndarray:
    """``(gx^2, gx gy, gy^2)`` of a float gray image (Scharr's derivatives), float32 ``(H, W, 3)``."""
    gx = cv2.Scharr(gray, cv2.CV_32F, 1, 0)
    gy = cv2.Scharr(gray, cv2.CV_32F, 0, 1)
    return np.stack([gx * gx, gx * gy, gy * gy], axis=-1)
