"""``projreg live``: the live loop on a camera or a video played in real time (registered on the app by
:mod:`projreg.cli`, which it does not import: the command line's one module would pass 600 lines)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from projsynth.utils.console import Bar, Quiet, fail, input_path, output_path

from .cli_options import Backend, Coverage, Device, Fast, MinConfidence, Precision, Quality, resolve_quality
from .errors import ProjregError

LIVE_QUALITY = "fast"  # the quality that keeps 10 registered frames per second at 384 x 512 on 2 cores


def live(
    captured: Annotated[
        str,
        typer.Option(
            help="The camera: an OpenCV camera index (0, 1, ...), or a video played as a camera in real time "
            "(frames arrive at its frame rate).",
            metavar="INDEX|VIDEO",
        ),
    ],
    content: Annotated[
        Path,
        typer.Option(
            help="What the projector is given to show: an image, or a video (played at its rate, looping).",
            parser=input_path,
            metavar="IMG|VIDEO",
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            help="Write the pre-warped frames as a video, one per registered frame (.mkv FFV1, .avi HuffYUV, .mp4).",
            parser=output_path,
            metavar="VIDEO",
        ),
    ] = None,
    stats: Annotated[
        Path | None,
        typer.Option(
            help="Write the summary and every frame's numbers (latency, step, drops) as JSON.",
            parser=output_path,
            metavar="FILE.json",
        ),
    ] = None,
    predict_motion: Annotated[
        bool,
        typer.Option(
            "--predict-motion",
            help="Carry each flow forward by the motion between the last two registrations, over the latency.",
        ),
    ] = False,
    frames: Annotated[
        int | None,
        typer.Option(help="Stop after N registered frames [default: when the camera ends, or Ctrl-C].", metavar="N"),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option(
            help="Checkpoint, or `reference`; default: the shipped reference model.", parser=input_path, metavar="CKPT"
        ),
    ] = None,
    quality: Quality = LIVE_QUALITY,
    fast: Fast = False,
    device: Device = None,
    precision: Precision = "fp32",
    backend: Backend = "auto",
    coverage: Coverage = "complete",
    min_confidence: MinConfidence = 0.0,
    fill: Annotated[int, typer.Option(help="Grey level of projector pixels without correspondence.")] = 0,
    quiet: Quiet = False,
) -> None:
    """Register a camera's frames as they arrive and pre-warp the content with the newest flow.

    Each frame is registered from the previous one (the first in full); frames that arrive while one is
    registered are dropped and counted. Ctrl-C stops cleanly and keeps what was written. At the end one
    line: frames in, registered, dropped, registered frames per second, latency (arrival to warp)."""
    from .api import Registrar
    from .inference.live import record_live
    from .inference.outputs import check_parent, guard_outputs, require_suffix
    from .inference.realtime import Content, DeviceCamera, PlayedVideo
    from .inference.video import check_video_suffix

    try:
        if frames is not None and frames < 1:
            raise ProjregError(f"--frames must be >= 1, got {frames}")
        if stats is not None:
            require_suffix(stats, ".json", "--stats")
        if not captured.strip():
            raise ProjregError("--captured: empty; give a camera index (0, 1, ...) or a video")
        index = int(captured) if captured.strip().isdigit() else None  # a camera, else a video played as one
        inputs = [("--content", content)] + ([("--captured", Path(captured))] if index is None else [])
        guard_outputs([("--out", out), ("--stats", stats)], inputs)
        for option, path in (("--out", out), ("--stats", stats)):
            if path is not None:
                check_parent(path, option)  # before the loop, not when its frames are written
        if out is not None:
            check_video_suffix(out, "--out")
        played = None if index is not None else PlayedVideo(Path(captured), "--captured")
        shown = Content(content, "--content")
        registrar = Registrar(
            model, quality=resolve_quality(quality, fast), device=device, precision=precision, backend=backend
        )
        loop = registrar.live(
            played or DeviceCamera(index, "--captured"),
            shown,
            predict_motion=predict_motion,
            coverage=coverage,
            min_confidence=min_confidence,
            fill=fill,
            limit=frames,
        )
        with Bar("live", quiet, unit="frame") as bar:
            summary = record_live(loop, out, stats, progress=lambda _: bar.update())
    except ProjregError as e:
        raise fail("projreg", e) from None
    latency = summary["latency_ms"] or {"median": float("nan"), "p95": float("nan")}
    stopped = " (stopped by Ctrl-C)" if summary["interrupted"] else ""
    steps = ", ".join(f"{n} {step}" for step, n in summary["steps"].items())
    typer.echo(
        f"live{stopped}: {summary['frames_in']} frames in, {summary['registered']} registered ({steps}), "
        f"{summary['dropped']} dropped; {summary['fps']:.1f} registered frames/s; latency (arrival to warp) "
        f"median {latency['median']:.0f} ms, p95 {latency['p95']:.0f} ms",
        err=True,
    )
