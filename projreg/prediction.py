"""What a method claims about its own flow: where it holds (``claimed``) and whether the pair registered.

Convention: ``flow`` float32 ``(H, W, 2)``, forward, projected -> captured, pixels; ``claimed`` bool
``(H, W)`` on the projected grid (None: every pixel); ``registered`` False when the method found no
evidence to register the pair at all (e.g. textureless content): its flow is then a placeholder;
``confidence`` float32 ``(H, W)`` in [0, 1], how sure the method is of each pixel (None: the method does
not measure it). Two questions, two outputs: ``claimed`` is the verified claim (confidence >= ``CONFIDENT``
on a registered pair), the flow is the method's best estimate on every pixel, claimed or not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CONFIDENT = 0.5  # a pixel is claimed (``valid`` in predict's EXR) when its confidence is at least this


@dataclass(frozen=True)
class Prediction:
    """A flow with the pixels its method vouches for; see the module docstring."""

    flow: np.ndarray
    claimed: np.ndarray | None = None
    registered: bool = True
    reason: str = ""
    confidence: np.ndarray | None = None


def as_prediction(out: np.ndarray | Prediction) -> Prediction:
    """A method's output as a :class:`Prediction` (a bare flow claims every pixel)."""
    return out if isinstance(out, Prediction) else Prediction(out)
