"""Re-render a generated sample with another projector image: what the camera would see.

A sample is a pure function of (plan, seed, id), so its scene, photometry, transparency field and
sensor-noise stream can be drawn again from ``dataset.json``; :class:`Rerenderer` does that and
photographs any projector image through them. Projecting the sample's own projected image gives its
stored captured image back, byte for byte (tested). This is how compensation is judged by what the
camera finally sees (``projreg bench --compensation``): each candidate pre-warp is photographed through
the same scene with the same noise.

Cost: the scene draw, the backward map and the blend, without the forward map, the flow EXR or the
shard write: less than generating the sample (docs/history/2026-11-log.md). Source images are regenerated once
per pair (built-in procedural sources only: a dataset made from folders needs those folders, which the
dataset does not hold).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ProjsynthError
from ..sim.photometric import noiseless
from ..sim.render import alpha_field, camera_view, expose
from .plan import Plan, resolve_plan, sample_key, sample_scene, source_images
from .shards import PLAN_FILE, read_json
from .transforms import builtin_table


@dataclass(frozen=True)
class View:
    """A camera photo ``(Hc, Wc, 3)`` uint8; ``lit`` ``(Hc, Wc)``: the pixels the projector lights, and
    ``source`` ``(Hc, Wc, 2)``: the projector position (x, y) each camera pixel sees."""

    image: np.ndarray
    lit: np.ndarray
    source: np.ndarray


def plan_of(root: Path) -> Plan:
    """The plan that generated the dataset in ``root``, rebuilt from its ``dataset.json`` and checked
    against the recorded config hash."""
    path = Path(root) / PLAN_FILE
    info = read_json(path, "plan")
    if "captured" in info:
        raise ProjsynthError(f"{path}: a captured dataset (photographs) cannot be re-rendered; use a generated one")
    if info.get("sources") is not None:
        raise ProjsynthError(
            f"{path}: made from image folders, which the dataset does not hold; re-rendering "
            "needs a dataset of built-in sources"
        )
    if info.get("table_digest") != builtin_table().digest():
        raise ProjsynthError(f"{path}: made with a custom transform table; re-rendering needs the built-in one")
    try:
        plan = resolve_plan(
            size=tuple(info["size"]),
            seed=info["seed"],
            split=info["split"],
            pairs=info["pairs"],
            transforms=",".join(str(t) for t in info["transforms"]),
            blend=info["blend"],
            frames=info.get("frames", 1),
            motion=info.get("motion"),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise ProjsynthError(f"{path}: not a projsynth plan ({e}); regenerate the dataset") from e
    if plan.config_hash() != info.get("config_hash"):
        raise ProjsynthError(
            f"{path}: written by another projsynth version or edited (config hash differs); regenerate the dataset"
        )
    return plan


class Rerenderer:
    """Photograph projector images through the scenes of a generated dataset's samples."""

    def __init__(self, root: Path):
        self.plan = plan_of(root)
        self._images: tuple[int, tuple] | None = None  # the last pair's source images

    def _sources(self, k: int) -> tuple:
        pair = sample_key(self.plan, k)[0]
        if self._images is None or self._images[0] != pair:
            self._images = (pair, source_images(self.plan, pair))
        return self._images[1]

    def views(self, k: int, images: list[np.ndarray], same_noise: bool = True, *, noise: bool = True) -> list[View]:
        """Sample ``k``'s camera photo of each projector image (``(H, W, 3)`` uint8, the projector's
        frame), every one with the sample's own transparency field and noise stream (and, for a frame
        of a sequence, its exposure: the motion blur).

        ``same_noise``: every photo with the stored photo's noise draw, so that two views differ only by
        what was projected; False: each with a draw of its own (the stream continued, image after
        image), as photos shot one after another are, e.g. the grey levels of a response measurement.
        ``noise=False``: without the sensor's random noise (:func:`~projsynth.sim.photometric.noiseless`,
        photos averaged over many frames)."""
        s = sample_scene(self.plan, k, self._sources(k))
        photometry = s.photometry if noise else noiseless(s.photometry)
        alpha = alpha_field(s.projected.shape[:2], s.photometry["alpha"], s.photometry["alpha_var"], s.rng)
        stream = s.rng if s.noise is None else s.noise
        after_alpha = stream.bit_generator.state
        view = camera_view(s.scene)
        views = [camera_view(sub) for sub in s.exposure] or [view]
        hc, wc = s.scene.camera.height, s.scene.camera.width
        lit, source = view[1].reshape(hc, wc), view[0].T.reshape(hc, wc, 2)
        out = []
        for image in images:
            if image.shape != s.projected.shape:
                raise ProjsynthError(f"a projector image of shape {image.shape} for a {s.projected.shape} projector")
            if same_noise:
                stream.bit_generator.state = after_alpha  # the same noise for every image
            photo = expose(image, alpha, views, s.background, photometry, self.plan.blend, stream)
            out.append(View(photo, lit, source))
        return out
