"""Pre-warp content for projection: what the projector must show so the camera sees ``content``.

Convention: with the forward flow ``F`` (projected -> captured, on the projector grid), projector
pixel ``p`` lands on camera pixel ``p + F(p)``. To make the camera see ``content`` (an image in the
camera frame), the projector shows ``content`` sampled at ``p + F(p)``; no inversion of the flow is
needed. Projector pixels whose flow is invalid (they miss the surface, are hidden from the camera, or
land outside its frame, or whose flow is NaN or Inf) are set to ``fill``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.flow.formats import read_flow_exr
from projsynth.structured.response import read_response
from projsynth.utils.images import load_image

from ..errors import ProjregError
from ..geometry.warp import lands_inside, pixel_maps
from .outputs import guard_outputs, require_suffix, write_png
from .radiometric import CLIPPED_SHARE, calibrate, solve


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
    cam_h, cam_w = camera_size or (h, w)
    valid = lands_in_frame(flow, valid, (cam_h, cam_w))
    if not valid.any():
        raise ProjregError(
            "flow has no finite valid vector inside the camera frame: nothing to compensate; check the flow file"
        )
    ch, cw = content.shape[:2]
    xs, ys = pixel_maps(h, w)
    flow = np.where(valid[..., None], flow, 0).astype(np.float32)
    # camera position in content pixels (pixel centres at integers in both frames)
    mx = (xs + flow[..., 0] + 0.5) * (cw / cam_w) - 0.5
    my = (ys + flow[..., 1] + 0.5) * (ch / cam_h) - 0.5
    out = cv2.remap(content, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out[~valid] = fill
    return out


def lands_in_frame(flow: np.ndarray, valid: np.ndarray, camera_size: tuple[int, int]) -> np.ndarray:
    """``valid`` where the flow is finite and lands inside the camera frame ``(Hc, Wc)`` (pixel centres
    at integers: positions in ``[-0.5, Wc - 0.5] x [-0.5, Hc - 0.5]``); elsewhere a projector pixel has
    no camera pixel to take its content from."""
    return np.asarray(valid, bool) & lands_inside(flow, camera_size, 0.5)


def _camera_size(header: dict[str, str], flow: Path) -> tuple[int, int] | None:
    """The camera frame ``(Hc, Wc)`` a flow EXR's positions are in (``predict`` writes ``camera_size``);
    None when the header does not say (the flow's own grid is then taken for the camera's)."""
    text = header.get("camera_size")
    if text is None:
        return None
    try:
        hc, wc = (int(v) for v in text.split("x"))
    except ValueError:
        raise ProjregError(f"--flow {flow}: header camera_size {text!r} is not HxW; write the flow again") from None
    return hc, wc


def compensate_files(
    content: Path,
    flow: Path,
    out: Path,
    fill: int = 0,
    photometric: tuple[Path, Path] | None = None,
    gamma: float = 2.2,
    response: Path | None = None,
) -> dict:
    """``projreg compensate``: read a desired view and a flow EXR, write the projector image (PNG).

    Returns:
        ``size`` ``(H, W)`` of the projector image, ``lit``, the share of its pixels that show content
        (a valid flow landing in the camera frame; the others get ``fill``), and ``warnings``: lines
        for the user (a saturated white photo).

    ``photometric``: the camera's photos ``(white, black)`` of a full-white and a full-black
    projection; the desired view is then also corrected for the surface's colour and light
    (:mod:`projreg.inference.radiometric`) in the photos' frame before the geometric pre-warp, with the
    devices' curves of the ``response`` file (``projsynth response``), or ``gamma`` for both without one.
    """
    require_suffix(Path(out), ".png", "--out")
    inputs = [("--content", Path(content)), ("--flow", Path(flow))]
    inputs += [] if photometric is None else [("--white", Path(photometric[0])), ("--black", Path(photometric[1]))]
    inputs += [] if response is None else [("--response", Path(response))]
    guard_outputs([("--out", Path(out))], inputs)
    if not 0 <= fill <= 255:
        raise ProjregError(f"--fill: must be in 0..255, got {fill}")
    try:
        image = load_image(Path(content))
        f, valid, header = read_flow_exr(Path(flow))
        photos = None if photometric is None else [load_image(Path(p)) for p in photometric]
        curves = None if response is None else read_response(Path(response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    camera, warnings = _camera_size(header, flow), []
    if photos is not None:
        model = calibrate(photos[0], photos[1], gamma, response=curves)
        if camera is not None and camera != photos[0].shape[:2]:
            raise ProjregError(
                f"--white {photometric[0]}: {photos[0].shape[1]}x{photos[0].shape[0]} px, but the flow's camera "
                f"frame is {camera[1]}x{camera[0]}; shoot the photos with the camera the flow was measured with"
            )
        camera = photos[0].shape[:2]
        image = solve(cv2.resize(image, camera[::-1], interpolation=cv2.INTER_AREA), model)[0]
        if model.clipped > CLIPPED_SHARE:
            warnings.append(
                f"--white {photometric[0]}: saturated on {model.clipped:.0%} of the frame, where the projector's "
                "gain is underestimated; shoot it again with a shorter exposure"
            )
    try:
        projector = compensate(image, f, valid, fill, camera_size=camera)
    except ProjregError as e:
        raise ProjregError(f"--flow {flow}: {e}") from e
    write_png(Path(out), projector)
    lit = lands_in_frame(f, valid, camera or valid.shape)
    return {"size": tuple(projector.shape[:2]), "lit": float(lit.mean()), "warnings": warnings}
