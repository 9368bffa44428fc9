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

from ..checks import check_number
from ..errors import ProjregError
from ..geometry.warp import lands_inside, pixel_maps
from .outputs import guard_outputs, require_suffix, write_png
from .radiometric import CLIPPED_SHARE, Radiometry, calibrate, solve
from .sources import Frames, survey
from .video import VideoWriter, check_fps

COVERAGES = ("complete", "claimed")  # which projector pixels show content (module docstring)
PREDICTED = "valid_threshold"  # the header attribute of `projreg predict`'s EXR (its flow is finite everywhere)
ASPECT_TOLERANCE = 0.02  # content whose aspect ratio differs from the camera frame's by more is refused
DEFAULT_FPS = 30.0  # a video's frame rate when neither --fps nor a content video gives one (the simulator's)


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
    check_coverage(coverage, min_confidence)
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


def check_coverage(coverage: str, min_confidence: float) -> None:
    """Refuse a coverage that is not one of ``COVERAGES`` or a confidence threshold that is not a number
    in [0, 1] (a bool, a string, None)."""
    if coverage not in COVERAGES:
        raise ProjregError(f"--coverage must be one of {', '.join(COVERAGES)}, got {coverage!r}")
    check_number("--min-confidence", min_confidence, 0.0, 1.0)


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
    fps: float | None = None,
) -> dict:
    """``projreg compensate``: read a desired view and a flow EXR, write the projector image (PNG); or, for
    a content video (or folder of frames) and/or a folder of flow EXRs (``predict --track``'s, taken in
    name order), write the projector's video, frame ``k`` the content's frame ``k`` (a still image: every
    frame) pre-warped by flow ``k`` (one EXR: every frame; a fixed rig), at ``fps`` frames per second
    (None: the content video's rate, else ``DEFAULT_FPS``), whole or not at all
    (:class:`~projreg.inference.video.VideoWriter`).

    Returns:
        ``size`` ``(H, W)`` of the projector image, ``lit``, the share of its pixels that show content
        (the others get ``fill``; a video: the mean over its frames), ``registered`` (False: a flow's pair
        was not registered and its content is projected as it is, module docstring), ``frames`` (a
        video: how many; an image: None), ``unregistered`` (a video: the frames projected as they are),
        and ``warnings``: lines for the user (a saturated white photo).

    ``photometric``: the camera's photos ``(white, black)`` of a full-white and a full-black
    projection; the desired view is then also corrected for the surface's colour and light
    (:mod:`projreg.inference.radiometric`) in the photos' frame before the geometric pre-warp, with the
    devices' curves of the ``response`` file (``projsynth response``), or ``gamma`` for both without one.
    ``coverage`` and ``min_confidence``: which projector pixels show content (:func:`shown_pixels`).

    Raises:
        ProjregError: one line naming the option: a content's and the flows' frame counts that differ, a
            frame or flow that does not read, an output suffix that is not the output's format, an ``fps``
            out of (0, ``MAX_FPS``] or given for a picture (refused, not ignored).
    """
    fps = None if fps is None else check_fps(fps, "--fps")
    contents, flows = Frames(Path(content), "--content"), _flow_files(Path(flow))
    video = contents.sequence or Path(flow).is_dir()
    if fps is not None and not video:
        raise ProjregError(
            "--fps sets the frame rate of a video; a still --content and one --flow EXR give one picture (PNG): "
            "drop --fps"
        )
    if video:
        writer = VideoWriter(Path(out), fps or contents.fps or DEFAULT_FPS)  # its suffix checked now
    else:
        require_suffix(Path(out), ".png", "--out")
    inputs = [("--content", p) for p in contents.files] + [("--flow", p) for p in flows]
    inputs += [] if photometric is None else [("--white", Path(photometric[0])), ("--black", Path(photometric[1]))]
    inputs += [] if response is None else [("--response", Path(response))]
    guard_outputs([("--out", Path(out))], inputs)
    if not 0 <= fill <= 255:
        raise ProjregError(f"--fill: must be in 0..255, got {fill}")
    count = _frame_count(contents, flows, Path(flow))
    try:
        photos = None if photometric is None else [load_image(Path(p)) for p in photometric]
        curves = None if response is None else read_response(Path(response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    model = None if photos is None else calibrate(photos[0], photos[1], gamma, response=curves)
    warnings = []
    if model is not None and model.clipped > CLIPPED_SHARE:
        warnings.append(
            f"--white {photometric[0]}: saturated on {model.clipped:.0%} of the frame, where the projector's "
            "gain is underestimated; shoot it again with a shorter exposure"
        )
    pictures = iter(contents)  # a still image: without end
    options = {"fill": fill, "coverage": coverage, "min_confidence": min_confidence, "white": photometric}
    if not video:
        projector, lit, registered = _compensate_frame(next(pictures), flows[0], photos, model, options)
        write_png(Path(out), projector)
        size, frames, unregistered = tuple(projector.shape[:2]), None, int(not registered)
    else:
        shares, unregistered = [], 0
        with writer:
            for k in range(count):
                projector, share, registered = _compensate_frame(
                    next(pictures), flows[k % len(flows)], photos, model, options
                )
                writer.write(projector)
                shares.append(share)
                unregistered += not registered
        size, frames, lit, registered = writer.size, count, float(np.mean(shares)), unregistered == 0
    return {
        "size": size,
        "lit": lit,
        "registered": registered,
        "frames": frames,
        "unregistered": unregistered,
        "warnings": warnings,
    }


def _compensate_frame(
    image: np.ndarray, flow: Path, photos: list[np.ndarray] | None, model: Radiometry | None, options: dict
) -> tuple[np.ndarray, float, bool]:
    """One content frame pre-warped by the flow file ``flow`` (:func:`compensate_files`): the projector
    image, the share of its pixels lit with content, and whether the flow's pair registered."""
    try:
        f = read_flow_file(flow)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    coverage, min_confidence = options["coverage"], options["min_confidence"]
    registered, coverage = file_coverage(f, coverage, min_confidence)
    shown = shown_pixels(f.valid, f.confidence, coverage, min_confidence)
    # without a stated frame, the photos' (they are the camera's), else the flow's own grid
    camera = stated_camera_size(f.header, flow) or (photos[0].shape[:2] if photos is not None else f.valid.shape)
    check_aspect(image.shape, camera)
    if photos is not None:
        if camera != photos[0].shape[:2]:
            raise ProjregError(
                f"--white {options['white'][0]}: {photos[0].shape[1]}x{photos[0].shape[0]} px, but the flow's camera "
                f"frame is {camera[1]}x{camera[0]}; shoot the photos with the camera the flow was measured with"
            )
        image = solve(cv2.resize(image, camera[::-1], interpolation=cv2.INTER_AREA), model)[0]
    try:
        projector = prewarp(
            image,
            f.flow,
            claimed=f.valid,
            confidence=f.confidence,
            registered=registered,
            coverage=coverage,
            min_confidence=min_confidence,
            fill=options["fill"],
            camera_size=camera,
        )
    except ProjregError as e:
        raise ProjregError(f"--flow {flow}: {e}") from e
    lit = float(content_mask(f.flow, shown, registered, coverage, camera).mean())
    return projector, lit, registered


def _flow_files(flow: Path) -> list[Path]:
    """``--flow``: one EXR, or a folder's EXRs in relative name order (``predict``'s output folder)."""
    if not flow.is_dir():
        return [flow]
    files = sorted(
        (p for p in flow.rglob("*") if p.suffix.lower() == ".exr" and not p.name.startswith(".")),
        key=lambda p: p.relative_to(flow).as_posix(),
    )
    if not files:
        raise ProjregError(
            f"--flow {flow}: no flow EXR in this folder; point --flow at `projreg predict --track`'s output"
        )
    return files


def _frame_count(contents: Frames, flows: list[Path], flow: Path) -> int:
    """The frames of the video to write: the flows' number (a folder), else the content's (a still
    content: 1); a content folder or video (read once now, :func:`~projreg.inference.sources.survey`) and
    a folder of flows must hold as many.

    Raises:
        ProjregError: the counts differ, or a content frame does not read (before anything is written).
    """
    if not contents.sequence:
        return len(flows) if flow.is_dir() else 1
    known = len(contents.files) if contents.kind == "folder" else len(survey(contents, check_size=False))
    if flow.is_dir() and known != len(flows):
        raise ProjregError(
            f"--content {contents.path} has {known} frames but --flow {flow} holds {len(flows)} flow EXRs; the "
            "content and the flows are paired frame by frame, so both need as many (nothing was written)"
        )
    return known
