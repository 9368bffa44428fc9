"""``projreg compensate``: pre-warp content, a picture or a video (registered on the app by
:mod:`projreg.cli`, which it does not import: the command line's one module would pass 600 lines)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from projsynth.utils.console import fail, input_path, output_path

from .cli_options import Coverage, MinConfidence, ResponseFile
from .errors import ProjregError


def compensate(
    content: Annotated[
        Path,
        typer.Option(
            help="Desired camera view: an image, or a video (or folder) of frames.",
            parser=input_path,
            metavar="IMG|VIDEO|DIR",
        ),
    ],
    flow: Annotated[
        Path,
        typer.Option(
            help="Flow EXR projected -> captured (from `projreg predict`), or a folder of them, one per frame "
            "in name order (`predict --track`).",
            parser=input_path,
            metavar="FILE.exr|DIR",
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            help="Projector image to write (PNG); a video (.mkv FFV1 or .avi HuffYUV, lossless; .mp4 MPEG-4) when "
            "--content is a video or folder or --flow a folder.",
            parser=output_path,
            metavar="FILE.png|VIDEO",
        ),
    ],
    fill: Annotated[int, typer.Option(help="Grey level of projector pixels without correspondence.")] = 0,
    photometric: Annotated[
        bool, typer.Option("--photometric", help="Also correct colour and light (needs --white and --black).")
    ] = False,
    white: Annotated[
        Path | None, typer.Option(help="Camera photo of a full-white projection.", parser=input_path, metavar="IMG")
    ] = None,
    black: Annotated[
        Path | None, typer.Option(help="Camera photo of a full-black projection.", parser=input_path, metavar="IMG")
    ] = None,
    response: ResponseFile = None,
    gamma: Annotated[
        float | None,
        typer.Option(
            help="Without --response: projector and camera gamma of the photometric model [default: 2.2].",
            show_default=False,
        ),
    ] = None,
    coverage: Coverage = "complete",
    min_confidence: MinConfidence = 0.0,
    fps: Annotated[
        float | None,
        typer.Option(
            help="A video's frame rate [default: the content video's, else 30].", show_default=False, metavar="FPS"
        ),
    ] = None,
) -> None:
    """Pre-warp content: the projector image that makes the camera see CONTENT undistorted.

    By default every projector pixel whose flow lands in the camera frame shows content (a pair reported
    as not registered: the content as it is); the flow's confidence and claim are information, not a mask
    (--coverage claimed, --min-confidence). A content video and a folder of flows give a video, frame by
    frame (a still image or one flow serves every frame)."""
    from .inference.compensate import compensate_files

    try:
        if photometric and (white is None or black is None):
            raise ProjregError(
                "--photometric needs --white and --black: the camera's photos of a full-white and "
                "a full-black projection"
            )
        calibration = {"--white": white, "--black": black, "--response": response, "--gamma": gamma}
        given = [option for option, value in calibration.items() if value is not None]
        if not photometric and given:
            raise ProjregError(f"{given[0]} sets the photometric correction; add --photometric")
        if response is not None and gamma is not None:
            raise ProjregError("--gamma is the assumption --response replaces by a measurement; drop --gamma")
        photos = (white, black) if photometric else None
        gamma = 2.2 if gamma is None else gamma
        result = compensate_files(content, flow, out, fill, photos, gamma, coverage, min_confidence, response, fps)
    except ProjregError as e:
        raise fail("projreg", e) from None
    for line in result["warnings"]:
        typer.echo(f"projreg: warning: {line}", err=True)
    h, w = result["size"]
    how = "geometric + photometric" if photometric else "geometric"
    how += " with the measured response" if response is not None else ""
    if result["frames"] is not None:
        if result["unregistered"] and coverage == "complete":
            typer.echo(
                f"projreg: warning: {flow}: {result['unregistered']} of {result['frames']} frames' pairs were not "
                "registered; their content is projected as it is",
                err=True,
            )
        typer.echo(
            f"{out}: {w}x{h} projector video of {result['frames']} frames ({how}), content on {result['lit']:.1%} "
            f"of its pixels (mean), --fill {fill} elsewhere",
            err=True,
        )
        return
    if not result["registered"] and coverage == "complete":
        how = "photometric only" if photometric else "uncompensated"
        typer.echo(
            f"projreg: warning: {flow}: its pair was not registered; the content is projected as it is", err=True
        )
    typer.echo(
        f"{out}: {w}x{h} projector image ({how}), content on {result['lit']:.1%} of its pixels, "
        f"--fill {fill} elsewhere",
        err=True,
    )
