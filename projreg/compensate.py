"""Pre-warp content for projection: what the projector must show so the camera sees ``content``.

Convention: with the forward flow ``F`` (projected -> captured, on the projector grid), projector
pixel ``p`` lands on camera pixel ``p + F(p)``. To make the camera see ``content`` (an image in the
camera frame), the projector shows ``content`` sampled at ``p + F(p)``; no inversion of the flow is
needed. Projector pixels whose flow is invalid (they miss the surface, are hidden from the camera, or
land outside its frame) and pixels whose flow is NaN or Inf are set to ``fill``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from projsynth import ProjsynthError
from projsynth.flowio import read_flow_exr
from projsynth.sources import load_image

from . import ProjregError
from .predict import refuse_overwriting_inputs, require_suffix, write_png
from .radiometric import calibrate, solve


def compensate(
    content: np.ndarray,
    flow: np.ndarray,
    valid: np.ndarray,
    fill: int = 0,
    camera_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """The projector image that makes the camera see ``content``.

    Args:
        content: ``(Hc', Wc', 3)`` uint8 RGB desired camera view, spanning the camera frame (any size:
            flow positions are scaled to it).
        flow: ``(H, W, 2)`` float32 forward flow projected -> captured, in pixels of the camera frame.
        valid: ``(H, W)`` bool; pixels with non-finite flow count as invalid too.
        fill: value of projector pixels without a valid correspondence.
        camera_size: the camera frame ``(Hc, Wc)`` the flow's positions are in; None: ``(H, W)``.

    Returns:
        ``(H, W, 3)`` uint8 projector image.

    Raises:
        ProjregError: the flow's shape differs from ``valid``'s, or no pixel has a valid, finite flow.
    """
    h, w = valid.shape
    if flow.shape != (h, w, 2):
        raise ProjregError(f"flow has shape {flow.shape}, expected {(h, w, 2)}")
    valid = valid & np.isfinite(flow).all(axis=-1)  # NaN/Inf flow has no correspondence: filled, like invalid
    if not valid.any():
        raise ProjregError("flow has no finite valid vector: nothing to compensate; check the flow file")
    ch, cw = content.shape[:2]
    cam_h, cam_w = camera_size or (h, w)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    # camera position in content pixels (pixel centres at integers in both frames)
    mx = (xs + flow[..., 0] + 0.5) * (cw / cam_w) - 0.5
    my = (ys + flow[..., 1] + 0.5) * (ch / cam_h) - 0.5
    out = cv2.remap(content, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out[~valid] = fill
    return out


def compensate_files(
    content: Path,
    flow: Path,
    out: Path,
    fill: int = 0,
    photometric: tuple[Path, Path] | None = None,
    gamma: float = 2.2,
) -> dict:
    """``projreg compensate``: read a desired view and a flow EXR, write the projector image (PNG).

    Returns:
        ``size`` ``(H, W)`` of the projector image and ``lit``, the share of its pixels that show
        content (a valid, finite flow; the others get ``fill``).

    ``photometric``: the camera's photos ``(white, black)`` of a full-white and a full-black
    projection; the desired view is then also corrected for the surface's colour and light
    (:mod:`projreg.radiometric`) in the photos' frame before the geometric pre-warp.
    """
    require_suffix(Path(out), ".png", "--out")
    inputs = [("--content", Path(content)), ("--flow", Path(flow))]
    inputs += [] if photometric is None else [("--white", Path(photometric[0])), ("--black", Path(photometric[1]))]
    refuse_overwriting_inputs([("--out", Path(out))], inputs)
    if not 0 <= fill <= 255:
        raise ProjregError(f"--fill: must be in 0..255, got {fill}")
    try:
        image = load_image(Path(content))
        f, valid, _ = read_flow_exr(Path(flow))
        photos = None if photometric is None else [load_image(Path(p)) for p in photometric]
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    camera = None
    if photos is not None:
        model = calibrate(photos[0], photos[1], gamma)
        camera = photos[0].shape[:2]
        image = solve(cv2.resize(image, camera[::-1], interpolation=cv2.INTER_AREA), model)[0]
    try:
        projector = compensate(image, f, valid, fill, camera_size=camera)
    except ProjregError as e:
        raise ProjregError(f"--flow {flow}: {e}") from e
    write_png(Path(out), projector)
    lit = np.asarray(valid, bool) & np.isfinite(f).all(axis=-1)
    return {"size": tuple(projector.shape[:2]), "lit": float(lit.mean())}
