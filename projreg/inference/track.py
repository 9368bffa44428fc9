"""Tracking registration: each frame of a sequence starts from the previous frame's flow.

Between two camera frames of a moving rig the projector-camera map changes only a little, so a frame
need not be registered from scratch:

1. The first frame, and a frame on which the track is lost, is registered in full (``register``:
   the network and the geometric refinement, :mod:`projreg.refine`).
2. Every other frame is the geometric refinement from the previous frame's flow instead of the
   network's (``GeometricRefiner.predict_info`` with ``identity=False``): the homography fitted to
   it, then (``balanced``, ``fast``) the direct alignment on the normalised images only, started from
   the previous answer's smooth surface (its homography and a fine P-spline of the rest: the surface's
   bend carries over from frame to frame) and not polished (``TrackConfig``), or (``accurate``) DIS
   residuals and the smooth surface model on normalised, plain and albedo images, the best scored; a
   tracked frame the first stage leaves unverified escalates to the DIS search of every view as a full
   one does. The network does not run. The previous answer is only a start: the flow is measured
   afresh on the frame's images.
3. The tracked flow's score (the refinement's texture-weighted local NCC) is compared with the score
   of the last full registration: below it by more than ``drop``, or below ``floor``, or when the
   previous flow has no homography fit, the track is lost and the frame is registered in full.

What the tracked flow claims is the refinement's per-pixel confidence, as for a full registration.
Classical baselines track without a score (:class:`FlowTracker`): each frame is the baseline's flow
between the projected image and the captured image warped back by the previous flow, composed onto it.

Convention: flows are float32 ``(H, W, 2)``, forward, projected -> captured, pixels, on the projected
grid; ``projected`` and ``captured`` uint8 RGB ``(H, W, 3)`` of one size.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..geometry.warp import compose, warp_back
from ..prediction import Prediction, as_prediction
from ..refine.refiner import GeometricRefiner

STEPS = ("full", "tracked", "lost")  # how a frame was registered: first frame, from the previous, re-registered


@dataclass(frozen=True)
class TrackConfig:
    """The lost-track test on the score (module docstring, step 3), set by hand, not tuned on a split
    (docs/design.md); and how a refinement that aligns directly (``align.direct``) follows a frame."""

    drop: float = 0.08  # a tracked score this far below the last full registration's loses the track
    floor: float = 0.2  # ... as does one below this
    views: tuple[str, ...] = ("normalised",)  # a tracked frame is aligned on these views only ...
    from_surface: bool = True  # ... from the last answer's smooth surface (its bend), not its homography ...
    polish: tuple[str, ...] = ()  # ... and not polished by DIS (it adds DIS's noise to a bend already in the start)


class Tracker:
    """A model's tracking registration over the frames of one sequence at a time (module docstring).

    ``register(projected, captured)``: the full registration (a flow or a Prediction). Call
    :meth:`reset` before each sequence; ``counts`` tells how each frame since went (``STEPS``) and
    ``last`` how the last one did.
    """

    def __init__(
        self,
        register: Callable[[np.ndarray, np.ndarray], np.ndarray | Prediction],
        refiner: GeometricRefiner | None = None,
        config: TrackConfig | None = None,
    ) -> None:
        self.register = register
        self.refiner = refiner or GeometricRefiner()
        self.config = config or TrackConfig()
        cfg = self.refiner.config
        tc = self.config
        light = {"views": tc.views, "polish": tc.polish, "from_surface": tc.from_surface} if cfg.align.direct else {}
        # a tracked frame follows a registration whose capture was checked for a mirror and whose claim the frame's
        # alignment confirmed: neither is asked again (a frame's claim shrinks as the projection leaves the view);
        # its claim is the checks' (the pinning on a bent surface, 12-16 ms, is the full registrations': a
        # real-time loop's frames)
        follow = {"mirror_side": None, "confirm_below": 0.0, "pin": False}
        self.follow = GeometricRefiner(cfg.with_sections(align=light, confidence=follow))
        self.counts = dict.fromkeys(STEPS, 0)
        self.last = ""
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame: the next one is registered in full."""
        self._flow: np.ndarray | None = None
        self._reference = 0.0  # the score of the last full registration

    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> Prediction:
        """The registration of the next frame of the sequence."""
        if self._flow is not None:
            pred, info = self.follow.predict_info(projected, captured, self._flow, identity=False)
            score = info.scores.get(f"{info.hypothesis}/{info.images}", -1.0)
            if info.hypothesis == "network" and score >= max(self._reference - self.config.drop, self.config.floor):
                self._flow = pred.flow
                return self._done("tracked", pred)
        pred = as_prediction(self.register(projected, captured))
        step = "lost" if self._flow is not None else "full"
        self._flow = pred.flow if pred.registered else None
        self._reference = self.score(projected, captured, pred.flow)
        return self._done(step, pred)

    def score(self, projected: np.ndarray, captured: np.ndarray, flow: np.ndarray) -> float:
        """The refinement's selection score of ``flow`` on the pair (:meth:`GeometricRefiner.score`), the
        scale the tracked frames' scores are compared on."""
        return self.refiner.score(projected, captured, flow)

    def _done(self, step: str, pred: Prediction) -> Prediction:
        self.last = step
        self.counts[step] += 1
        return pred


class FlowTracker:
    """A dense flow method (a classical baseline) tracking: each frame's flow is the method's flow
    between ``projected`` and ``captured`` warped back by the previous flow, composed onto it; the
    first frame after :meth:`reset` is the method's own."""

    def __init__(self, flow: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> None:
        self.flow = flow
        self.counts = dict.fromkeys(STEPS, 0)
        self.reset()

    def reset(self) -> None:
        self._flow: np.ndarray | None = None

    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> Prediction:
        if self._flow is None:
            self._flow = np.asarray(self.flow(projected, captured), np.float32)
            self.counts["full"] += 1
        else:
            back = warp_back(captured, self._flow)
            self._flow = compose(self._flow, np.asarray(self.flow(projected, back), np.float32))
            self.counts["tracked"] += 1
        return Prediction(self._flow)


class JitterAccumulator:
    """Temporal jitter: how much a method's flow error changes from one frame to the next.

    For consecutive frames ``t-1, t`` of one sequence, with error ``e_t(p) = flow_t(p) - gt_t(p)``
    (a vector, px), the frame pair contributes ``|e_t(p) - e_{t-1}(p)|`` for every projected pixel
    ``p`` valid in both frames; ``jitter`` is the mean over all such pixels of all frame pairs
    (pooled, as EPE is). A constant error (the projection off by the same amount in every frame)
    has no jitter; an error that changes is what a viewer sees as the projection trembling.
    """

    def __init__(self) -> None:
        self.total, self.pixels = 0.0, 0
        self._last: tuple[str, np.ndarray, np.ndarray] | None = None

    def add(self, sequence: str, flow: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> None:
        """The next frame of ``sequence`` (a new sequence id starts afresh)."""
        err = np.asarray(flow, np.float64) - gt  # [H, W, 2]
        if self._last is not None and self._last[0] == sequence and self._last[1].shape == err.shape:
            both = valid & self._last[2]
            self.total += float(np.linalg.norm(err[both] - self._last[1][both], axis=-1).sum())
            self.pixels += int(both.sum())
        self._last = (sequence, err, valid)

    def result(self) -> float | None:
        return self.total / self.pixels if self.pixels else None
