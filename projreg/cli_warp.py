"""``projreg warp``: the pre-warp of ``compensate`` for show software (registered on the app by
:mod:`projreg.cli`, which it does not import: the command line's one module would pass 600 lines)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from projsynth.utils.console import fail, input_path, output_path

from .cli_options import Coverage, MinConfidence
from .errors import ProjregError


def _parse_content_size(text: str | None) -> tuple[int, int] | None:
    """``--content-size WxH`` (a video's way, ``1920x1080``) as ``(H, W)``."""
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ProjregError(f"--content-size: expected WxH such as 1920x1080, got {text!r}") from None
    return h, w


def warp(
    flow: Annotated[
        Path,
        typer.Option(
            help="Flow EXR projected -> captured (from `projreg predict`).", parser=input_path, metavar="FILE.exr"
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            help="The warp to write: .exr (STMap), .obj (mesh) or .npz (cv2.remap maps).",
            parser=output_path,
            metavar="FILE",
        ),
    ],
    step: Annotated[
        int | None,
        typer.Option(
            help=".obj: projector pixels between the mesh's vertices [default: 16].", show_default=False, metavar="N"
        ),
    ] = None,
    content_size: Annotated[
        str | None,
        typer.Option(
            help=".npz: the content's size in pixels, such as 1920x1080 [default: the camera frame's].",
            show_default=False,
            metavar="WxH",
        ),
    ] = None,
    coverage: Coverage = "complete",
    min_confidence: MinConfidence = 0.0,
) -> None:
    """Export the pre-warp for show software: an STMap, a mesh or cv2.remap maps.

    The format follows the suffix of --out. Each maps every projector pixel to the content point it
    shows, on the pixels `projreg compensate` gives content with the same flow and options;
    docs/show.md says how to load each in Nuke, TouchDesigner, Resolume, MadMapper, Unreal or OpenCV."""
    from .inference.warpfiles import export_warp_file

    try:
        size = _parse_content_size(content_size)
        result = export_warp_file(
            flow, out, step=step, content_size=size, coverage=coverage, min_confidence=min_confidence
        )
    except ProjregError as e:
        raise fail("projreg", e) from None
    if result["as_it_is"]:
        typer.echo(
            f"projreg: warning: {flow}: its pair was not registered; the map projects content as it is", err=True
        )
    h, w = result["size"]
    shown = f"content on {result['shown']:.1%} of its pixels"
    if result["format"] == "mesh":
        what = (
            f"{w}x{h} mesh, {result['vertices']} vertices, {result['triangles']} triangles (a vertex every "
            f"{result['step']} px) over {result['covered']:.1%} of the pixels with content; interpolation error "
            f"{result['error_mean']:.3f} px mean, {result['error_max']:.3f} px max (camera pixels)"
        )
    elif result["format"] == "STMap":
        what = f"{w}x{h} STMap (32-bit float RGBA), {shown}"
    else:
        ch, cw = result["content_size"]
        what = f"{w}x{h} cv2.remap maps for {cw}x{ch} content, {shown}"
    typer.echo(f"{out}: {what}", err=True)
