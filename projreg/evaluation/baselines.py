"""Classical registration baselines with the same interface as the models: ``predict(projected, captured)``.

Convention: ``projected`` and ``captured`` are uint8 RGB ``(H, W, 3)`` of the same size; the returned
flow is float32 ``(H, W, 2)``, forward, projected -> captured, in pixels: ``flow[y, x] = (u, v)`` means
projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.

Preprocessing is the same for every baseline, so that the comparison is fair: both images are turned
to grayscale with ``cv2.COLOR_RGB2GRAY`` and, when ``equalize=True``, each is histogram-equalised
with ``cv2.equalizeHist`` (this compensates global contrast/brightness changes between the projector
frame buffer and the camera image, at the cost of amplifying noise in flat regions).

Baselines (``BASELINES``):

* ``dis-ultrafast``, ``dis-fast``, ``dis-medium``: OpenCV DIS optical flow at its three presets.
* ``farneback``: OpenCV Farneback with pyr_scale 0.5, 5 levels, a 21 px window, 5 iterations,
  poly_n 7, poly_sigma 1.5 (large window and deep pyramid for the large, smooth motions of projection).
* ``sift-ransac``: SIFT matches (Lowe's ratio test 0.75), a RANSAC homography (3 px reprojection
  threshold, ``cv2.setRNGSeed(0)`` first for determinism), then the dense flow ``H(p) - p``. When
  fewer than 4 matches survive, no homography is found, or the homography sends part of the image
  through infinity, the flow is all zeros and ``last_status`` says why.
* ``refine-only``: the geometric refinement of :mod:`projreg.refine` without the network: its
  hypotheses are the identity and the ``sift-ransac`` homography (the identity alone when SIFT finds
  none), so a bench row beside the model's shows what the network adds. It claims pixels and reports
  unregistered pairs as the refined model does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from ..errors import ProjregError
from ..geometry.homography import SiftHomography, homography_flow
from ..geometry.images import to_gray
from ..prediction import Prediction
from ..refine.config import SEARCH
from ..refine.refiner import GeometricRefiner


class Baseline(Protocol):
    """Anything that maps an image pair to a forward flow, projected -> captured."""

    name: str

    def predict(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray | Prediction: ...


class _OpenCVBaseline:
    """Checks the pair, applies the shared preprocessing and hands two gray images to ``_flow``."""

    name = ""

    def __init__(self, equalize: bool = False) -> None:
        self.equalize = equalize

    def predict(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray:
        """Forward flow ``(H, W, 2)`` float32, projected -> captured, pixels (see the module docstring)."""
        for role, img in (("projected", projected), ("captured", captured)):
            if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
                got = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
                raise ProjregError(f"{role} must be a uint8 RGB array (H, W, 3), got {got}")
        if projected.shape != captured.shape:
            raise ProjregError(
                f"projected {projected.shape} and captured {captured.shape} differ; resize them to one size"
            )
        gray0 = to_gray(projected, self.equalize)
        gray1 = to_gray(captured, self.equalize)
        return np.ascontiguousarray(self._flow(gray0, gray1), dtype=np.float32)

    def _flow(self, gray0: np.ndarray, gray1: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class DIS(_OpenCVBaseline):
    """OpenCV DIS flow; ``calc(I0, I1)`` returns ``F`` with ``I0(p) ~ I1(p + F(p))``: forward already."""

    PRESETS = {
        "ultrafast": cv2.DISOpticalFlow_PRESET_ULTRAFAST,
        "fast": cv2.DISOpticalFlow_PRESET_FAST,
        "medium": cv2.DISOpticalFlow_PRESET_MEDIUM,
    }

    def __init__(self, preset: str, equalize: bool = False) -> None:
        if preset not in self.PRESETS:
            raise ProjregError(f"unknown DIS preset {preset!r}; choose from {', '.join(self.PRESETS)}")
        super().__init__(equalize)
        self.name = f"dis-{preset}"
        self._dis = cv2.DISOpticalFlow_create(self.PRESETS[preset])

    def _flow(self, gray0: np.ndarray, gray1: np.ndarray) -> np.ndarray:
        return self._dis.calc(gray0, gray1, None)


class Farneback(_OpenCVBaseline):
    """OpenCV Farneback flow; ``prev(p) ~ next(p + F(p))``, forward with prev = projected."""

    name = "farneback"
    PARAMS = {"pyr_scale": 0.5, "levels": 5, "winsize": 21, "iterations": 5, "poly_n": 7, "poly_sigma": 1.5}

    def _flow(self, gray0: np.ndarray, gray1: np.ndarray) -> np.ndarray:
        return cv2.calcOpticalFlowFarneback(gray0, gray1, None, flags=0, **self.PARAMS)


class SiftRansac(_OpenCVBaseline):
    """SIFT + ratio test + RANSAC homography (:class:`~projreg.geometry.homography.SiftHomography`), densified as
    ``H(p) - p``.

    After each ``predict``, ``last_status`` is ``"ok"``, ``"too-few-matches"``, ``"no-homography"`` or
    ``"degenerate"`` (the flow is zero unless ``"ok"``) and ``last_inliers`` the RANSAC inlier count.
    """

    name = "sift-ransac"

    def __init__(self, equalize: bool = False) -> None:
        super().__init__(equalize)
        self._estimator = SiftHomography()
        self.last_status = "not-run"
        self.last_inliers = 0

    def _flow(self, gray0: np.ndarray, gray1: np.ndarray) -> np.ndarray:
        h, w = gray0.shape
        H, self.last_status, self.last_inliers = self._estimator(gray0, gray1)
        return np.zeros((h, w, 2), np.float32) if H is None else homography_flow(H, h, w)


_WITHOUT_SIFT = SEARCH.with_sections(search={"sift": False})


class RefineOnly:
    """The refinement started without the network: from the identity and from a SIFT homography (the full
    one-stage search, :data:`~projreg.refine.config.SEARCH`, whose own SIFT start would repeat this one)."""

    name = "refine-only"

    def __init__(self, equalize: bool = False) -> None:
        self._sift = SiftRansac(equalize)
        self._refiner = GeometricRefiner(_WITHOUT_SIFT)  # its SIFT start comes from here

    def predict(self, projected: np.ndarray, captured: np.ndarray) -> Prediction:
        """The refined flow with the pixels it claims (:meth:`GeometricRefiner.predict`)."""
        start = self._sift.predict(projected, captured)  # zero flow (the identity) without a homography
        return self._refiner.predict(projected, captured, start)


BASELINES: dict[str, Callable[[bool], Baseline]] = {
    "dis-ultrafast": lambda eq: DIS("ultrafast", eq),
    "dis-fast": lambda eq: DIS("fast", eq),
    "dis-medium": lambda eq: DIS("medium", eq),
    "farneback": Farneback,
    "sift-ransac": SiftRansac,
    "refine-only": RefineOnly,
}


def make_baseline(name: str, equalize: bool = False) -> Baseline:
    """A fresh baseline by registry name; ``equalize`` turns on histogram equalisation for both images."""
    if name not in BASELINES:
        raise ProjregError(f"unknown baseline {name!r}; choose from {', '.join(BASELINES)}")
    return BASELINES[name](equalize)


def parse_baselines(spec: str) -> list[str]:
    """Comma-separated baseline names -> list in the given order, duplicates dropped, each checked.

    Example:
        >>> parse_baselines("dis-fast, farneback")
        ['dis-fast', 'farneback']
    """
    names = list(dict.fromkeys(s.strip() for s in spec.split(",") if s.strip()))
    if not names:
        raise ProjregError(f"no baseline named in {spec!r}; choose from {', '.join(BASELINES)}")
    for name in names:
        if name not in BASELINES:
            raise ProjregError(f"unknown baseline {name!r}; choose from {', '.join(BASELINES)}")
    return names
