"""``bench --photos``: each model again on the capture with the surface divided out by the rig's photos.

For every sample of a generated dataset, the camera's photos of a full-white and a full-black
projection are rendered through the sample's own scene (:class:`projsynth.dataset.rerender.Rerenderer`)
without the sensor's random noise: a fixed rig's photos averaged over several frames, as docs/model.md
advises to shoot them (single noisy photos add their noise to every normalised capture; measured in
docs/design.md). Each model method ``NAME`` then also runs as ``NAME+photos`` on
:func:`projreg.inference.photos.normalise_capture` of the captured image; its flow is scored against
the same truth as always.

The white photo is of full white (255), not the ``closedloop.WHITE_LEVEL`` of the photometric
calibration: the simulated camera saturates there on some pixels, but registration was measured better
with it (docs/design.md), and a full-white photo needs no projector response to be read.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from projsynth.dataset.rerender import Rerenderer
from projsynth.errors import ProjsynthError

from ..errors import ProjregError
from ..geometry.frames import resize_to
from ..inference.photos import normalise_capture
from ..prediction import Prediction
from .methods import Method

SUFFIX = "+photos"


class RigPhotos:
    """The white and black photos of the sample being scored (:meth:`shoot`), and the methods that
    register with them (:meth:`methods`)."""

    def __init__(self, data: Path) -> None:
        try:
            self.rerenderer = Rerenderer(Path(data))
        except ProjsynthError as e:
            raise ProjregError(f"--photos: {e}") from e
        self.photos: tuple[np.ndarray, np.ndarray] | None = None

    def shoot(self, k: int, sample: dict) -> None:
        """Sample ``k``'s (its reader dict) photos of a full-white and a full-black projection."""
        projected = sample["projected"]
        try:
            views = self.rerenderer.views(k, [np.full_like(projected, 255), np.zeros_like(projected)], noise=False)
        except ProjsynthError as e:
            raise ProjregError(f"--photos: sample {k}: {e}") from e
        self.photos = (views[0].image, views[1].image)

    def methods(self, methods: Sequence[Method]) -> list[Method]:
        """``NAME+photos`` for every model method (tracking ones aside)."""
        return [
            Method(m.name + SUFFIX, m.kind, self._divided(m.predict), m.refined)
            for m in methods
            if m.kind == "model" and m.tracker is None
        ]

    def _divided(self, predict: Callable) -> Callable[[np.ndarray, np.ndarray], np.ndarray | Prediction]:
        def run(projected: np.ndarray, captured: np.ndarray) -> np.ndarray | Prediction:
            # shot before any registration; resized for a camera of another size, as the captured image
            white, black = (resize_to(p, captured.shape) for p in self.photos)
            return predict(projected, normalise_capture(captured, white, black))

        return run
