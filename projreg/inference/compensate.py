"""Pre-warp content for projection: what the projector must show so the camera sees ``content``.

Convention: with the forward flow ``F`` (projected -> captured, on the projector grid), projector
pixel ``p`` lands on camera pixel ``p + F(p)``. To make the camera see ``content`` (an image in the
camera frame), the projector shows ``content`` sampled at ``p + F(p)``; no inversion of the flow is
needed.

Which projector pixels show content is a decision for the viewer, apart from what the registration
verified (docs/design.md, "What the camera sees"). By default (**complete** coverage) every projector
pixel whose flow is finite and lands inside the camera frame shows content, claimed or not: the
refined flow is the pipeline's best estimate there, and on the unclaimed pixels it is still far closer
than any alternative. ``claimed`` coverage keeps only the pixels the registration vouches for (its
``valid``); ``min_confidence`` keeps those whose confidence reaches a threshold the operator chose
(the reliability table of docs/results.md says what a level means). A pair reported as **not
registered** is projected as it is (the content resized to the projector's frame): measured on two
physical-model splits, its unverified flow showed the viewer no better than no compensation
(docs/history/2026-12-04-complete-compensation.md). Elsewhere projector pixels get ``fill``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.flow.formats import FlowFile, read_flow_file
from projsynth.structured.response import read_response
from projsynth.utils.images import load_image

from ..errors import ProjregError
from ..geometry.warp import lands_inside, pixel_maps
from .outputs import guard_outputs, require_suffix, write_png
from .radiometric import CLIPPED_SHARE, calibrate, solve

COVERAGES = ("complete", "claimed")  # which projector pixels show content (module docstring)
PREDICTED = "valid_threshold"  # the header attribute of `projreg predict`'s EXR (its flow is finite everywhere)
ASPECT_TOLERANCE = 0.02  # content whose aspect ratio differs from the camera frame's by more is refused


def compensate(
    content: np.ndarray,
    flow: np.ndarray,
    valid: np.ndarray | None = None,
    fill: int = 0,
    camera_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """The projector image that makes the camera see ``content``: the geometric pre-warp.

    Args:
        content: ``(Hc', Wc', 3)`` uint8 RGB desired camera view, spanning the camera frame (any size:
            flow positions are scaled to it).
        flow: ``(H, W, 2)`` float32 forward flow projected -> captured, in pixels of the camera frame.
        valid: ``(H, W)`` bool, the projector pixels that may show content (None: every one); pixels
            whose flow is not finite or lands outside the camera frame never do.
        fill: value of the projector pixels that show no content.
        camera_size: the camera frame ``(Hc, Wc)`` the flow's positions are in; None: ``(H, W)``.

    Returns:
        ``(H, W, 3)`` uint8 projector image.

    Raises:
        ProjregError: the flow's shape differs from ``valid``'s, or no pixel has a finite flow inside
            the camera frame.
    """
    h, w = flow.shape[:2]
    if flow.ndim != 3 or flow.shape[2] != 2 or (valid is not None and valid.shape != (h, w)):
        raise ProjregError(f"flow has shape {flow.shape}, expected (H, W, 2) on the grid of valid {valid.shape}")
    cam_h, cam_w = camera_size or (h, w)
    valid = lands_in_frame(flow, np.ones((h, w), bool) if valid is None else valid, (cam_h, cam_w))
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


def shown_pixels(
    claimed: np.ndarray | None,
    confidence: np.ndarray | None,
    coverage: str = "complete",
    min_confidence: float = 0.0,
) -> np.ndarray | None:
    """The projector pixels a coverage lets show content (module docstring), before the frame test of
    :func:`compensate`: None for every pixel.

    Raises:
        ProjregError: an unknown coverage, a threshold outside [0, 1], or one asked of a flow without
            confidence.
    """
    if coverage not in COVERAGES:
        raise ProjregError(f"--coverage must be one of {', '.join(COVERAGES)}, got {coverage!r}")
    if not 0 <= min_confidence <= 1:
        raise ProjregError(f"--min-confidence must be in 0..1, got {min_confidence}")
    if coverage == "claimed":
        return None if claimed is None else np.asarray(claimed, bool)
    if min_confidence > 0:
        if confidence is None:
            raise ProjregError(
                "--min-confidence: the flow carries no per-pixel confidence (written by the network alone, an "
                "older projreg or another tool); run `projreg predict` again, or drop --min-confidence"
            )
        return np.asarray(confidence) >= min_confidence
    return None


def prewarp(
    content: np.ndarray,
    flow: np.ndarray,
    *,
    claimed: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    registered: bool = True,
    coverage: str = "complete",
    min_confidence: float = 0.0,
    fill: int = 0,
    camera_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """The projector image for ``content`` by a registration's flow, under the coverage policy of the
    module docstring (what ``projreg compensate`` and :func:`projreg.api.compensate` do).

    A pair not ``registered`` is projected as it is (``content`` resized to the projector's grid),
    except with ``claimed`` coverage, where nothing is claimed and :func:`compensate` refuses.
    """
    shown = shown_pixels(claimed, confidence, coverage, min_confidence)
    if as_it_is(registered, coverage):
        h, w = flow.shape[:2]
        return cv2.resize(content, (w, h), interpolation=cv2.INTER_AREA)
    return compensate(content, flow, shown, fill, camera_size)


def as_it_is(registered: bool, coverage: str) -> bool:
    """Whether the content is projected as it is, unwarped: a pair not registered, with the complete
    coverage (module docstring; with ``claimed`` coverage such a pair shows nothing)."""
    return not registered and coverage == "complete"


def file_coverage(f: FlowFile, coverage: str, min_confidence: float) -> tuple[bool, str]:
    """A flow file's ``registered`` and the coverage in force for it, the options checked: a flow not
    written by ``projreg predict`` (ground truth, another tool) is defined only where its ``valid`` says,
    so its coverage is ``claimed`` whatever was asked."""
    shown_pixels(f.valid, f.confidence, coverage, min_confidence)  # the options checked as asked
    registered = f.header.get("registered", "yes") != "no"  # ground truth and other tools' flows say nothing
    return registered, coverage if PREDICTED in f.header else "claimed"


def content_mask(
    flow: np.ndarray, shown: np.ndarray | None, registered: bool, coverage: str, camera_size: tuple[int, int]
) -> np.ndarray:
    """The projector pixels that :func:`prewarp` gives content, bool ``(H, W)``: every one for a pair not
    registered (projected as it is), else those of ``shown`` (None: all) whose flow lands in the frame."""
    everywhere = np.ones(flow.shape[:2], bool)
    if as_it_is(registered, coverage):
        return everywhere
    return lands_in_frame(flow, everywhere if shown is None else shown, camera_size)


def check_aspect(content: tuple[int, ...], camera: tuple[int, int], name: str = "--content") -> None:
    """Refuse content whose aspect ratio is not the camera frame's ``(Hc, Wc)``: it spans the frame, so
    it would be stretched."""
    if min(content[:2]) < 1:
        raise ProjregError(f"{name} is empty ({content[1]}x{content[0]} px); give the picture to show")
    ratio = (content[1] / content[0]) / (camera[1] / camera[0])
    if abs(ratio - 1) > ASPECT_TOLERANCE:
        raise ProjregError(
            f"{name} is {content[1]}x{content[0]} px (aspect {content[1] / content[0]:.3f}) but the camera frame "
            f"is {camera[1]}x{camera[0]} ({camera[1] / camera[0]:.3f}): the content spans the camera frame, so it "
            "would be stretched; crop or pad it to the camera's aspect"
        )


def lands_in_frame(flow: np.ndarray, valid: np.ndarray, camera_size: tuple[int, int]) -> np.ndarray:
    """``valid`` where the flow is finite and lands inside the camera frame ``(Hc, Wc)`` (pixel centres
    at integers: positions in ``[-0.5, Wc - 0.5] x [-0.5, Hc - 0.5]``); elsewhere a projector pixel has
    no camera pixel to take its content from."""
    return np.asarray(valid, bool) & lands_inside(flow, camera_size, 0.5)


def stated_camera_size(header: dict[str, str], flow: Path) -> tuple[int, int] | None:
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
    coverage: str = "complete",
    min_confidence: float = 0.0,
    response: Path | None = None,
) -> dict:
    """``projreg compensate``: read a desired view and a flow EXR, write the projector image (PNG).

    Returns:
        ``size`` ``(H, W)`` of the projector image, ``lit``, the share of its pixels that show content
        (the others get ``fill``), ``registered`` (False: the flow's pair was not registered and the
        content is projected as it is, module docstring), and ``warnings``: lines for the user (a
        saturated white photo).

    ``photometric``: the camera's photos ``(white, black)`` of a full-white and a full-black
    projection; the desired view is then also corrected for the surface's colour and light
    (:mod:`projreg.inference.radiometric`) in the photos' frame before the geometric pre-warp, with the
    devices' curves of the ``response`` file (``projsynth response``), or ``gamma`` for both without one.
    ``coverage`` and ``min_confidence``: which projector pixels show content (:func:`shown_pixels`).
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
        f = read_flow_file(Path(flow))
        photos = None if photometric is None else [load_image(Path(p)) for p in photometric]
        curves = None if response is None else read_response(Path(response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    registered, coverage = file_coverage(f, coverage, min_confidence)
    shown = shown_pixels(f.valid, f.confidence, coverage, min_confidence)
    stated, warnings = stated_camera_size(f.header, flow), []
    # without a stated frame, the photos' (they are the camera's), else the flow's own grid
    camera = stated or (photos[0].shape[:2] if photos is not None else f.valid.shape)
    check_aspect(image.shape, camera)
    if photos is not None:
        model = calibrate(photos[0], photos[1], gamma, response=curves)
        if camera != photos[0].shape[:2]:
            raise ProjregError(
                f"--white {photometric[0]}: {photos[0].shape[1]}x{photos[0].shape[0]} px, but the flow's camera "
                f"frame is {camera[1]}x{camera[0]}; shoot the photos with the camera the flow was measured with"
            )
        image = solve(cv2.resize(image, camera[::-1], interpolation=cv2.INTER_AREA), model)[0]
        if model.clipped > CLIPPED_SHARE:
            warnings.append(
                f"--white {photometric[0]}: saturated on {model.clipped:.0%} of the frame, where the projector's "
                "gain is underestimated; shoot it again with a shorter exposure"
            )
    try:
        projector = prewarp(
            image,
            f.flow,
            claimed=f.valid,
            confidence=f.confidence,
            registered=registered,
            coverage=coverage,
            min_confidence=min_confidence,
            fill=fill,
            camera_size=camera,
        )
    except ProjregError as e:
        raise ProjregError(f"--flow {flow}: {e}") from e
    write_png(Path(out), projector)
    lit = float(content_mask(f.flow, shown, registered, coverage, camera).mean())
    return {"size": tuple(projector.shape[:2]), "lit": lit, "registered": registered, "warnings": warnings}
