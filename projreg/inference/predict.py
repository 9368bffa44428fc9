"""``projreg predict``: run a trained model on real (projected, captured) image pairs.

Each pair gives the forward flow, projected -> captured, written as the shards' flow EXR (channels
``forward.u``, ``forward.v``, ``valid``) and, optionally, a colour-wheel PNG. With the refinement,
``valid`` is 1 where the refinement's confidence is at least ``CONFIDENT`` (0.5; docs/model.md) on a
registered pair, the channel ``confidence`` holds that confidence (0..1) on every pixel, and the header
says whether the pair registered at all (``registered``, ``claimed``, ``reason``). The flow is the best
estimate on every pixel, claimed or not, and finite everywhere (``compensate`` uses all of it by
default). The network alone (``refine=False``) measures no confidence (no channel) and claims every
pixel.

The captured image may have another size than the projected one (a camera is not a projector): it
is resized for the network and the flow is given in its own pixels (:mod:`projreg.geometry.frames`).

With the camera's photos of a full-white and a full-black projection (``white``, ``black``), every
captured image is registered with the surface divided out (:mod:`projreg.inference.photos`): one pair
of photos for every pair and frame, as a fixed rig takes them; the EXR header's ``photos`` says so.

Folders, videos and still images (:mod:`projreg.inference.sources`): two folders pair their images by
relative name; a video on either side pairs frame by frame in order with the other side's video or
folder (name order), and a still projected image pairs with every captured frame. Every frame is read
once before the first flow is written (frame counts that differ, a frame that does not read, and in
tracking a frame of another size are refused then, and nothing is written).

Tracking (``track=True``): the pairs are one sequence in order; the first is registered in full, each
next one from the previous one's flow (:mod:`projreg.inference.track`); the EXR header's ``tracking``
says which (``full``, ``tracked`` or ``lost``: re-registered in full).

Convention: images uint8 RGB ``(H, W, 3)``; flow float32 ``(H, W, 2)`` on the projected grid,
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.flow.formats import encode_flow_exr
from projsynth.flow.pictures import flow_picture, scale_of
from projsynth.structured.response import read_response
from projsynth.utils.files import write_atomic_all
from projsynth.utils.images import png_bytes

from ..errors import ProjregError
from ..model.checkpoint import resolve_checkpoint
from ..prediction import CONFIDENT
from ..refine.config import DEFAULT_QUALITY
from ..refine.config import quality as resolve_quality
from .outputs import guard_outputs, require_suffix
from .pipeline import Pipeline
from .register import Photos, Registration, rig_photos
from .runtime import DEFAULT_BACKEND
from .sources import Frames, load, paired_count, survey


@dataclass(frozen=True)
class Predicted:
    """What ``predict`` wrote for one pair: the EXR, its sample id, whether the pair registered (if
    not, ``reason`` says why: its flow is zero and no pixel is valid) and the share of valid pixels."""

    out: Path
    sample_id: str
    registered: bool
    claimed: float
    reason: str
    tracking: str = ""  # tracking mode: "full", "tracked" or "lost"


@dataclass(frozen=True)
class Job:
    """Where one pair's outputs go (``viz`` None: no PNG) and its sample id."""

    out: Path
    viz: Path | None
    sample_id: str


def plan_jobs(projected: Frames, captured: Frames, out: Path, viz: Path | None, count: int = 1) -> list[Job]:
    """The outputs of file mode (two image files), folder mode (two folders, pairs by identical relative
    names) or sequence mode (a video on either side, or a still projected image with a folder or video of
    captured frames: frames paired in order, ``count`` pairs).

    Folder mode writes ``OUT/REL/STEM_flow.exr`` (and ``VIZ/REL/STEM_flow.png``) for every
    ``REL/STEM.ext`` of the projected folder; the EXR's sample id is the relative path. Sequence mode
    names them after the captured frames: a folder's relative paths, a video's frame numbers
    (``OUT/000000_flow.exr``, ...; sample id ``VIDEO#000000``).
    """
    out = Path(out)
    if not projected.sequence and not captured.sequence:
        require_suffix(out, ".exr", "--out")
        if viz is not None:
            require_suffix(Path(viz), ".png", "--viz")
        return [Job(out, viz, projected.path.name)]
    if not captured.sequence:
        raise ProjregError(
            f"--projected {projected.path} is a {projected.kind} but --captured {captured.path} is one image; give "
            "the captured frames as a folder or a video (a still --projected image stands for every frame)"
        )
    named = projected if projected.kind == captured.kind == "folder" else captured
    if named is projected:
        names = ids = _matched_names(projected, captured)
    else:
        names = captured.names(count)
        ids = names if captured.kind == "folder" else [f"{captured.path.name}#{name}" for name in names]
    jobs, seen = [], {}
    for name, sample_id in zip(names, ids, strict=True):
        stem = Path(name).with_suffix("").as_posix() + "_flow"
        if stem in seen:
            raise ProjregError(
                f"{named.path / name} and {named.path / seen[stem]} would both write {out / stem}.exr; rename one"
            )
        seen[stem] = name
        jobs.append(Job(out / f"{stem}.exr", None if viz is None else Path(viz) / f"{stem}.png", sample_id))
    return jobs


def _matched_names(projected: Frames, captured: Frames) -> list[str]:
    """Folder mode's relative names, every one in both folders (both name orders are then one)."""
    rel0, rel1 = projected.names(len(projected.files)), captured.names(len(captured.files))
    set0, set1 = set(rel0), set(rel1)
    for rel in rel0:
        if rel not in set1:
            raise ProjregError(
                f"{projected.path / rel}: no captured partner {captured.path / rel}; "
                "pairs match by identical relative file names"
            )
    for rel in rel1:
        if rel not in set0:
            raise ProjregError(
                f"{captured.path / rel}: no projected partner {projected.path / rel}; "
                "pairs match by identical relative file names"
            )
    return rel0


def predict(
    projected: Path,
    captured: Path,
    out: Path,
    *,
    viz: Path | None = None,
    model: Path | None = None,
    max_side: int = 1024,
    refine: bool = True,
    device: str | None = None,
    precision: str = "fp32",
    backend: str = DEFAULT_BACKEND,
    batch_size: int = 1,
    quality: str = DEFAULT_QUALITY,
    progress: Callable[[int, int], None] | None = None,
    max_flow: float | None = None,
    track: bool = False,
    white: Path | None = None,
    black: Path | None = None,
    response: Path | None = None,
) -> list[Predicted]:
    """Predict the flow of one pair of files, of every pair of two folders, or of every pair of frames.

    Args:
        projected, captured: two image files; two folders (pairs by identical relative names); or frames
            paired in order (:mod:`projreg.inference.sources`): a video on either side, the other side a
            video or a folder, or a still projected image for every captured frame (:func:`plan_jobs`).
        out: the EXR file (file mode) or the output folder (the other modes).
        viz: colour PNG file (file mode) or folder (the other modes); None writes none.
        model: a ``projreg train`` checkpoint; None or ``reference``: the shipped reference model; with
            ``backend="onnxruntime"`` a graph written by ``projreg export --onnx``.
        max_side: longest side the network sees at most (also bounded by the quality's ``network_side``);
            larger pairs are resized (:func:`projreg.inference.runtime.shrink`).
        refine: follow the network with the geometric refinement (``projreg.refine``), at the
            pair's own resolution; the EXR's ``valid`` is then its confidence >= ``CONFIDENT``.
        device, precision, backend: where and how the network runs (:func:`projreg.inference.runtime.open_network`);
            device None: CUDA when available, else the CPU.
        batch_size: pairs per network call (folder mode; pairs of one size are batched).
        quality: ``fast``, ``balanced`` (the default) or ``accurate`` (:data:`projreg.refine.config.QUALITIES`):
            the network's side and how the refinement searches.
        progress: called ``(done, total)`` after each pair.
        max_flow: the ``viz`` pictures' colours saturate at this magnitude (px); None: each picture's
            largest (``projsynth.flow.pictures.flow_picture``, with its legend).
        track: the pairs are the frames of one sequence, in order (module docstring).
        white, black: the camera's photos of a full-white and a full-black projection (``black``
            optional), of every captured image's size: each captured image is registered with the
            surface divided out (module docstring).
        response: with ``white``, a ``projsynth response`` file: the photos linearised by the devices'
            measured curves instead of gamma 2.2.

    Returns:
        One :class:`Predicted` per pair, in pair order (the caller warns about unregistered pairs).
    """
    if max_side < 16:
        raise ProjregError(f"--max-side must be >= 16, got {max_side}")
    resolve_quality(quality)  # an unknown quality refused before any file is read
    if batch_size < 1:
        raise ProjregError(f"--batch-size must be >= 1, got {batch_size}")
    if max_flow is not None:
        try:
            scale_of(np.zeros((1, 1, 2), np.float32), None, max_flow)
        except ProjsynthError as e:
            raise ProjregError(str(e)) from None
    if track and not refine:
        raise ProjregError("--track follows each frame with the refinement; drop --no-refine")
    if track and batch_size > 1:
        raise ProjregError("--track registers frame after frame; drop --batch-size")
    sides = Frames(projected, "--projected"), Frames(captured, "--captured")
    if batch_size > 1 and not (sides[0].sequence or sides[1].sequence):
        raise ProjregError(
            "--batch-size batches the pairs of folders or videos; two image files are one pair: drop --batch-size"
        )
    if track and not sides[1].sequence:
        raise ProjregError(
            f"--track: --captured {captured} is one image; give the frames of one sequence: two folders or videos, "
            "or a still --projected image with a folder or video of captured frames"
        )
    in_order = sides[1].sequence and not sides[0].kind == sides[1].kind == "folder"  # paired by order, not names
    shapes = _surveyed(sides, track) if in_order else None
    count = paired_count(*sides, tuple(len(s) for s in shapes)) if shapes else 1
    jobs = plan_jobs(*sides, out, viz, count)
    weights = model if backend == "onnxruntime" else resolve_checkpoint(model)
    guard_outputs(
        [(opt, p) for j in jobs for opt, p in (("--out", j.out), ("--viz", j.viz))],
        [(side.option, p) for side in sides for p in side.files]
        + [(opt, Path(p)) for opt, p in (("--model", weights), ("--white", white), ("--black", black)) if p]
        + ([("--response", Path(response))] if response else []),
    )
    if shapes is None and (track or white is not None):
        shapes = _surveyed(sides, track)  # before any pair is registered and written
    photos = _photos(sides[1], None if shapes is None else shapes[1], white, black, response)
    pipeline = Pipeline(
        weights, quality=quality, device=device, precision=precision, backend=backend, refine=refine, max_side=max_side
    )
    pairs = zip(islice(sides[0], len(jobs)), islice(sides[1], len(jobs)), strict=True)
    if track:
        regs = pipeline.track(pairs, photos)
    else:
        regs = _batches(pipeline, pairs, batch_size, photos)
    results = []
    for job, reg in zip(jobs, regs, strict=True):
        results.append(_write(job, reg, refine, max_flow, photos))
        if progress:
            progress(len(results), len(jobs))
    return results


def _batches(
    pipeline: Pipeline, pairs: Iterator[tuple[np.ndarray, np.ndarray]], batch_size: int, photos: Photos | None
) -> Iterator[Registration]:
    """The pairs registered ``batch_size`` at a time, each batch read when the last one is written."""
    while chunk := list(islice(pairs, batch_size)):
        yield from pipeline.register(chunk, batch_size, photos)


def _surveyed(sides: tuple[Frames, Frames], track: bool) -> list[list[tuple[int, ...]]]:
    """Both sides' frames read once (:func:`~projreg.inference.sources.survey`): every frame reads and, for
    a tracked sequence, has its side's first frame's size."""
    return [survey(side, check_size=track) for side in sides]


def _photos(
    captured: Frames,
    shapes: list[tuple[int, ...]] | None,
    white: Path | None,
    black: Path | None,
    response: Path | None,
) -> Photos | None:
    """The rig's photos and response (:func:`~projreg.inference.register.rig_photos`), checked against the
    ``shapes`` of every captured frame (:func:`_surveyed`: read before any pair is registered and written)."""
    try:
        curves = None if response is None else read_response(Path(response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    photos = rig_photos(*(None if p is None else load(p) for p in (white, black)), curves)
    for k, shape in enumerate(shapes if photos is not None else ()):
        if shape != photos[0].shape:
            raise ProjregError(
                f"--white {white} is {photos[0].shape[1]}x{photos[0].shape[0]} px but --captured {captured.where(k)} "
                f"is {shape[1]}x{shape[0]}; shoot the photos with the camera of the captured images, at their size"
            )
    return photos


def _write(job: Job, reg: Registration, refined: bool, max_flow: float | None, photos: Photos | None) -> Predicted:
    """One pair's EXR (and PNG, its colours saturating at ``max_flow``), all or nothing; what was
    written. The header says whether the pair registered, the frame the flow's positions are in
    (``camera_size``), how the tracker registered a frame (``tracking``) and the rig's photos the
    captured image was divided by (``photos``)."""
    attrs = {
        "registered": "yes" if reg.registered else "no",
        "claimed": f"{reg.claimed.mean():.4f}",
        "valid_threshold": f"confidence >= {CONFIDENT}" if refined else "all (network alone)",
        "camera_size": f"{reg.camera_size[0]}x{reg.camera_size[1]}",
    }
    if reg.reason:
        attrs["reason"] = reg.reason
    if reg.step:
        attrs["tracking"] = reg.step
    if photos is not None:
        attrs["photos"] = "white and black" if photos[1] is not None else "white alone (ambient light kept)"
        attrs["photos"] += ", measured response" if photos[2] is not None else ", gamma 2.2"
    try:
        exr = encode_flow_exr(reg.flow, reg.claimed, job.sample_id, attrs=attrs, confidence=reg.confidence)
        files = [(job.out, exr)]
        if job.viz is not None:
            files.append((job.viz, png_bytes(job.viz, flow_picture(reg.flow, reg.claimed, max_flow))))
        write_atomic_all(files, make_parents=True)  # the flow and its picture, or neither
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    return Predicted(job.out, job.sample_id, reg.registered, float(reg.claimed.mean()), reg.reason, reg.step)
