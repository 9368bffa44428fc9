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

Tracking (``track=True``, two folders of frames): the pairs are one sequence in name order; the first
is registered in full, each next one from the previous one's flow (:mod:`projreg.inference.track`); the EXR
header's ``tracking`` says which (``full``, ``tracked`` or ``lost``: re-registered in full).

Convention: images uint8 RGB ``(H, W, 3)``; flow float32 ``(H, W, 2)`` on the projected grid,
``flow[y, x] = (u, v)`` means projected pixel ``(x, y)`` is seen at captured pixel ``(x + u, y + v)``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.flow.formats import encode_flow_exr
from projsynth.flow.pictures import flow_picture, scale_of
from projsynth.structured.response import read_response
from projsynth.utils.files import write_atomic_all
from projsynth.utils.images import list_images, load_image, png_bytes

from ..errors import ProjregError
from ..model.checkpoint import resolve_checkpoint
from ..prediction import CONFIDENT
from ..refine.config import DEFAULT_QUALITY
from ..refine.config import quality as resolve_quality
from .outputs import guard_outputs, require_suffix
from .pipeline import Pipeline
from .register import Photos, Registration, rig_photos
from .runtime import DEFAULT_BACKEND


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
    """One pair to predict and where its outputs go (``viz`` None: no PNG)."""

    projected: Path
    captured: Path
    out: Path
    viz: Path | None
    sample_id: str


def plan_jobs(projected: Path, captured: Path, out: Path, viz: Path | None) -> list[Job]:
    """File mode (two files) or folder mode (two folders, pairs by identical relative names).

    Folder mode writes ``OUT/REL/STEM_flow.exr`` (and ``VIZ/REL/STEM_flow.png``) for every
    ``REL/STEM.ext`` of the projected folder; the EXR's sample id is the relative path.
    """
    projected, captured, out = Path(projected), Path(captured), Path(out)
    if not projected.is_dir():
        if captured.is_dir():
            raise ProjregError(
                f"--projected {projected} is a file but --captured {captured} is a folder; "
                "give two files or two folders"
            )
        require_suffix(out, ".exr", "--out")
        if viz is not None:
            require_suffix(Path(viz), ".png", "--viz")
        return [Job(projected, captured, out, viz, projected.name)]
    if not captured.is_dir():
        raise ProjregError(
            f"--projected {projected} is a folder but --captured {captured} is not; give two files or two folders"
        )
    try:
        rel0 = [p.relative_to(projected).as_posix() for p in list_images(projected, "--projected")]
        rel1 = [p.relative_to(captured).as_posix() for p in list_images(captured, "--captured")]
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    set0, set1 = set(rel0), set(rel1)
    for rel in rel0:
        if rel not in set1:
            raise ProjregError(
                f"{projected / rel}: no captured partner {captured / rel}; pairs match by identical relative file names"
            )
    for rel in rel1:
        if rel not in set0:
            raise ProjregError(
                f"{captured / rel}: no projected partner {projected / rel}; "
                "pairs match by identical relative file names"
            )
    jobs, seen = [], {}
    for rel in rel0:
        stem = Path(rel).with_suffix("").as_posix() + "_flow"
        if stem in seen:
            raise ProjregError(
                f"{projected / rel} and {projected / seen[stem]} would both write {out / stem}.exr; rename one"
            )
        seen[stem] = rel
        jobs.append(
            Job(
                projected / rel,
                captured / rel,
                out / f"{stem}.exr",
                None if viz is None else Path(viz) / f"{stem}.png",
                rel,
            )
        )
    return jobs


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
    """Predict the flow of one pair of files, or of every pair of two folders.

    Args:
        projected, captured: two image files, or two folders (pairs by identical relative names).
        out: the EXR file (file mode) or the output folder (folder mode).
        viz: colour PNG file (file mode) or folder (folder mode); None writes none.
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
        track: the pairs of two folders are the frames of one sequence, in name order (module docstring).
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
    if track and not Path(projected).is_dir():
        raise ProjregError(
            f"--track: --projected {projected} is a file; give two folders of frames (taken in name order)"
        )
    if track and not refine:
        raise ProjregError("--track follows each frame with the refinement; drop --no-refine")
    if track and batch_size > 1:
        raise ProjregError("--track registers frame after frame; drop --batch-size")
    jobs = plan_jobs(projected, captured, out, viz)
    weights = model if backend == "onnxruntime" else resolve_checkpoint(model)
    guard_outputs(
        [(opt, p) for j in jobs for opt, p in (("--out", j.out), ("--viz", j.viz))],
        [(opt, p) for j in jobs for opt, p in (("--projected", j.projected), ("--captured", j.captured))]
        + [(opt, Path(p)) for opt, p in (("--model", weights), ("--white", white), ("--black", black)) if p]
        + ([("--response", Path(response))] if response else []),
    )
    photos = _photos(jobs[: 1 if track else len(jobs)], white, black, response)
    pipeline = Pipeline(
        weights, quality=quality, device=device, precision=precision, backend=backend, refine=refine, max_side=max_side
    )
    if track:
        _require_one_size(jobs)
        frames = ((_load(j.projected), _load(j.captured)) for j in jobs)
        regs = pipeline.track(frames, photos, where="--track frames")
    else:
        regs = _batches(pipeline, jobs, batch_size, photos)
    results = []
    for job, reg in zip(jobs, regs, strict=True):
        results.append(_write(job, reg, refine, max_flow, photos))
        if progress:
            progress(len(results), len(jobs))
    return results


def _batches(pipeline: Pipeline, jobs: list[Job], batch_size: int, photos: Photos | None) -> Iterator[Registration]:
    """The jobs' pairs registered ``batch_size`` at a time, each batch read when the last one is written."""
    for start in range(0, len(jobs), batch_size):
        chunk = jobs[start : start + batch_size]
        yield from pipeline.register([(_load(j.projected), _load(j.captured)) for j in chunk], batch_size, photos)


def _require_one_size(jobs: list[Job]) -> None:
    """Before any frame is registered (and its flow written): every frame of a sequence has the first
    one's projected and captured sizes, and every file reads. Costs one more decode per frame."""
    first: dict[str, tuple[Path, tuple[int, ...]]] = {}
    for job in jobs:
        for option, path in (("--projected", job.projected), ("--captured", job.captured)):
            shape = _load(path).shape
            ref = first.setdefault(option, (path, shape))
            if shape != ref[1]:
                raise ProjregError(
                    f"--track: {path} is {shape[1]}x{shape[0]} px but {ref[0]}, the sequence's first frame, is "
                    f"{ref[1][1]}x{ref[1][0]}; the frames of one sequence share one size (nothing was written)"
                )


def _photos(jobs: list[Job], white: Path | None, black: Path | None, response: Path | None) -> Photos | None:
    """The rig's photos and response (:func:`~projreg.inference.register.rig_photos`), checked against the
    captured image of every job (before any pair is registered and written; one more decode per pair)."""
    try:
        curves = None if response is None else read_response(Path(response))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    photos = rig_photos(*(None if p is None else _load(p) for p in (white, black)), curves)
    for job in jobs if photos is not None else ():
        shape = _load(job.captured).shape
        if shape != photos[0].shape:
            raise ProjregError(
                f"--white {white} is {photos[0].shape[1]}x{photos[0].shape[0]} px but --captured {job.captured} "
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


def _load(path: Path) -> np.ndarray:
    try:
        return load_image(path)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
