"""Options that several ``projreg`` commands share (``bench``, ``predict``, ``compensate``, ``warp``), declared once
as typed aliases, in the manner of ``projsynth.utils.console``'s ``MaxFlow`` and ``Quiet``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from projsynth.utils.console import input_path

from .errors import ProjregError
from .refine.config import DEFAULT_QUALITY

Device = Annotated[
    str | None,
    typer.Option(
        help="cpu, cuda or cuda:N (default: cuda when available, else cpu).", show_default=False, metavar="DEVICE"
    ),
]
Precision = Annotated[
    str,
    typer.Option(
        help="fp32, bf16 or fp16 (CUDA only) for the network's feature stages (docs/model.md).",
        metavar="fp32|bf16|fp16",
    ),
]
Backend = Annotated[
    str,
    typer.Option(
        help="auto (onnxruntime for the reference model or an .onnx --model on the CPU in fp32 where it is "
        "installed, else torch), torch (a checkpoint) or onnxruntime (a graph of `projreg export --onnx`, as "
        "--model).",
        metavar="auto|torch|onnxruntime",
    ),
]
Quality = Annotated[
    str,
    typer.Option(
        help="fast, balanced or accurate: where the network runs and how far the refinement searches (docs/model.md).",
        metavar="fast|balanced|accurate",
    ),
]
Fast = Annotated[bool, typer.Option("--fast", help="The same as --quality fast.")]
ResponseFile = Annotated[
    Path | None,
    typer.Option(
        help="The devices' curves measured by `projsynth response` (replaces gamma 2.2).",
        parser=input_path,
        metavar="FILE.json",
    ),
]

Coverage = Annotated[
    str,
    typer.Option(
        help="Which projector pixels show content: complete (every one whose flow lands in the camera "
        "frame) or claimed (only the flow's valid pixels).",
        metavar="complete|claimed",
    ),
]
MinConfidence = Annotated[
    float,
    typer.Option(help="complete: show content only where the flow's confidence is at least this (0..1).", metavar="C"),
]


def resolve_quality(quality: str, fast: bool) -> str:
    """``--quality``, with ``--fast`` as its alias for ``fast``."""
    if fast and quality not in (DEFAULT_QUALITY, "fast"):
        raise ProjregError(f"--fast is --quality fast; drop one of --fast and --quality {quality}")
    return "fast" if fast else quality
