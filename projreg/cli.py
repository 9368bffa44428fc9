"""The ``projreg`` command line: parse, call one library function, map errors to one line + exit 2."""

from __future__ import annotations

import math
import os
import sys
import traceback
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from projsynth.utils.console import PLAIN_HELP, Bar, Command, MaxFlow, Quiet, fail, input_path, is_rank0, output_path
from projsynth.utils.cores import available_cores

from .cli_compensate import compensate
from .cli_live import live
from .cli_options import (
    Backend,
    Device,
    Fast,
    Precision,
    Quality,
    ResponseFile,
    resolve_quality,
)
from .cli_warp import warp
from .errors import ProjregError
from .refine.config import DEFAULT_QUALITY

app = typer.Typer(**PLAIN_HELP, help="Train, benchmark and apply the SSJM projector-camera registration network.")


@app.callback()
def _root() -> None:
    """Train, benchmark and apply the SSJM projector-camera registration network."""


def _torch_threads() -> None:
    """torch's intra-op pool sized to the cores this process may use (an explicit OMP_NUM_THREADS,
    as torchrun sets for several ranks on one machine, is kept)."""
    import torch

    if "OMP_NUM_THREADS" not in os.environ:
        torch.set_num_threads(available_cores())


def _figure(x: float | None, unit: str = "") -> str:
    """A metric as people read it: 3 significant digits (``32.6``, ``0.123``), ``–`` when absent."""
    return "–" if x is None else f"{x:.3g}{unit}"


def _end_torchrun_worker(code: int) -> NoReturn:
    """End a torchrun worker once its process group is gone, skipping interpreter shutdown.

    A gloo worker that reaches interpreter finalisation can abort there ("terminate called without an
    active exception", SIGABRT: C++ communication threads outliving Python; pytorch/pytorch#190489,
    #179291); a CPU run in CI ended so once. Everything the run writes is closed by now (checkpoints
    are fsynced and renamed), so only the console streams need flushing.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _parse_crop(text: str) -> tuple[int, int] | None:
    if text.lower() == "none":
        return None
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ProjregError(f"--crop: expected HxW such as 256x320 or none, got {text!r}") from None
    if h < 32 or w < 32:
        raise ProjregError(f"--crop: {h}x{w} is too small (each side >= 32)")
    return h, w


@app.command(cls=Command)
def train(
    data: Annotated[
        list[Path],
        typer.Option(help="Training dataset directory (repeat for several).", parser=input_path, metavar="DIR"),
    ],
    out: Annotated[Path, typer.Option(help="Run directory.", parser=output_path, metavar="RUN")],
    val: Annotated[
        list[Path] | None,
        typer.Option(help="Validation dataset directory (repeatable).", parser=input_path, metavar="DIR"),
    ] = None,
    model: Annotated[str, typer.Option(help="small or base.", metavar="small|base")] = "small",
    no_ssjm: Annotated[bool, typer.Option("--no-ssjm", help="Build the ablation without SSJM.")] = False,
    steps: Annotated[int, typer.Option(help="Stop after this many optimiser steps (resume to go further).")] = 15000,
    schedule_steps: Annotated[int, typer.Option(help="Length of the OneCycle schedule (paper: 15000).")] = 15000,
    warmup_steps: Annotated[int, typer.Option(help="Linear warm-up steps of the schedule.")] = 100,
    batch_size: Annotated[int, typer.Option(help="Samples per step (per process under torchrun).", metavar="B")] = 8,
    lr: Annotated[float, typer.Option(help="Peak learning rate of the OneCycle schedule.")] = 4e-4,
    gamma: Annotated[
        float,
        typer.Option(
            help="Loss weight decay over the predictions, coarse to fine: gamma^(N-1-i) for the i-th of N "
            "(1: the 1/8 predictions weigh as much as the last)."
        ),
    ] = 0.9,
    seed: Annotated[int, typer.Option(help="Seed of initialisation, sample order and augmentation.", metavar="S")] = 0,
    crop: Annotated[
        str, typer.Option(help="Training crop HxW, or none for full frames.", metavar="HxW|none")
    ] = "256x320",
    workers: Annotated[int, typer.Option(help="DataLoader worker processes.", metavar="K")] = 2,
    val_every: Annotated[int, typer.Option(help="Validate every N steps.")] = 500,
    val_samples: Annotated[
        int, typer.Option(help="Validate on N samples spread over --val (best.pt is chosen on them).")
    ] = 64,
    ckpt_every: Annotated[int, typer.Option(help="Write last.pt every N steps.")] = 100,
    log_every: Annotated[int, typer.Option(help="Log a metrics row every N steps.")] = 10,
    amp: Annotated[bool, typer.Option(help="bf16 autocast (CUDA only; default off).", show_default=False)] = False,
    compile: Annotated[bool, typer.Option("--compile", help="torch.compile the model.")] = False,
    activation_checkpointing: Annotated[
        bool,
        typer.Option(
            help="Recompute attention in backward: less memory, ~15% slower steps (default off).", show_default=False
        ),
    ] = False,
    resume: Annotated[
        bool, typer.Option(help="Continue RUN/checkpoints/last.pt exactly (default off).", show_default=False)
    ] = False,
    init: Annotated[
        str | None,
        typer.Option(
            help="Start from this checkpoint's weights (`reference`: the "
            "shipped model) with a fresh optimizer and schedule: "
            "fine-tuning.",
            metavar="CKPT|reference",
        ),
    ] = None,
    quiet: Quiet = False,
) -> None:
    """Train the registration network on projsynth shards."""
    from .training.distributed import launched_by_torchrun
    from .training.train import TrainConfig
    from .training.train import train as run_training

    torchrun = launched_by_torchrun()
    quiet = quiet or not is_rank0()  # under torchrun, rank 0 speaks for the run
    _torch_threads()
    try:
        cfg = TrainConfig(
            data=[str(p) for p in data],
            out=str(out),
            val=[str(p) for p in val or []],
            model=model,
            use_ssjm=not no_ssjm,
            steps=steps,
            schedule_steps=schedule_steps,
            warmup_steps=warmup_steps,
            batch_size=batch_size,
            lr=lr,
            gamma=gamma,
            seed=seed,
            workers=workers,
            crop=_parse_crop(crop),
            val_every=val_every,
            val_samples=val_samples,
            ckpt_every=ckpt_every,
            log_every=log_every,
            amp=amp,
            compile=compile,
            activation_checkpointing=activation_checkpointing,
            init=init,
        )
        with Bar("train", quiet, unit="step") as bar, _ValBar(quiet) as val_bar:

            def progress(step: int, loss: float) -> None:
                bar.done(step, steps)
                if math.isfinite(loss):  # the loss is read from the device once per log interval
                    bar.bar.set_postfix(loss=f"{loss:.3f}", refresh=True)

            summary = run_training(cfg, resume=resume, progress=progress, val_progress=val_bar)
    except ProjregError as e:
        failure = fail("projreg", e)
        if torchrun:
            _end_torchrun_worker(failure.exit_code)
        raise failure from None
    except Exception:
        if torchrun:  # e.g. gloo's "connection closed" when another rank has failed: traceback, exit 1
            traceback.print_exc()
            _end_torchrun_worker(1)
        raise
    code = 0
    if summary["interrupted"]:
        code = 130 if summary["interrupted"] == "SIGINT" else 143  # 128 + the signal, as a shell reports it
        if is_rank0():  # even with --quiet: where the run stands must not pass unnoticed
            typer.echo(
                f"projreg: {summary['interrupted']}: stopped at step {summary['step']}; checkpoint "
                f"{summary['checkpoint']} written; the same command with --resume continues",
                err=True,
            )
    elif not quiet:
        typer.echo(train_summary(out, summary), err=True)
    if torchrun:
        _end_torchrun_worker(code)
    if code:
        raise typer.Exit(code)


def train_summary(out: Path, summary: dict) -> str:
    """The line a finished ``train`` prints: its step, last loss and best validation EPE, rounded."""
    best = "no validation" if summary["best_epe"] is None else f"best val EPE {_figure(summary['best_epe'], ' px')}"
    if not summary["steps_run"]:
        return f"{out}: already at step {summary['step']} (--steps); nothing to train, {best}"
    return f"{out}: step {summary['step']}, loss {_figure(summary['loss'])}, {best}"


class _ValBar:
    """One bar per validation, ``(done, total)`` samples; gone once the validation ends."""

    def __init__(self, quiet: bool):
        self.quiet, self.bar = quiet, None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = Bar("validate", self.quiet)
        self.bar.done(done, total)
        if done == total:
            self.bar.__exit__()
            self.bar = None

    def __enter__(self) -> _ValBar:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.__exit__()


@app.command(cls=Command)
def export(
    checkpoint: Annotated[
        Path | None,
        typer.Option(
            help="Checkpoint written by `projreg train` (last.pt or "
            "best.pt); with --onnx also `reference`, the default "
            "there.",
            parser=input_path,
            metavar="CKPT",
        ),
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Deployable checkpoint to write.", parser=output_path, metavar="FILE")
    ] = None,
    onnx: Annotated[
        Path | None,
        typer.Option(
            "--onnx",
            help="Write the network (no refinement) as an ONNX graph instead (needs the optional onnx extra).",
            parser=output_path,
            metavar="FILE.onnx",
        ),
    ] = None,
    opset: Annotated[int, typer.Option(help="ONNX opset of --onnx (16..23 with torch 2.13).", metavar="N")] = 18,
) -> None:
    """Strip a training checkpoint to weights + config + provenance, or export the network as ONNX."""
    from .inference.onnx_export import export_checkpoint_onnx
    from .model.checkpoint import export_checkpoint

    try:
        if (out is None) == (onnx is None):
            raise ProjregError(
                "give --out CKPT (a deployable checkpoint) or --onnx FILE.onnx (an ONNX graph of the "
                "network), one of them"
            )
        if onnx is not None:
            written = export_checkpoint_onnx(checkpoint, onnx, opset=opset)
            typer.echo(f"{written}: opset {opset}, {written.stat().st_size / 2**20:.2f} MiB", err=True)
            return
        if checkpoint is None:
            raise ProjregError("--out needs --checkpoint: the `projreg train` checkpoint to strip")
        slim = export_checkpoint(checkpoint, out)
    except ProjregError as e:
        raise fail("projreg", e) from None
    typer.echo(f"{out}: step {slim.get('step')}, {out.stat().st_size / 2**20:.2f} MiB", err=True)


PHOTOS_HELP = (
    "Also each model as NAME+photos: on the capture divided by white and black photos rendered through each "
    "sample's scene (generated data)."
)
COMPENSATION_HELP = "Also judge each flow by the camera's view of its compensation (generated data)."
PHOTOMETRIC_HELP = "With --compensation: geometric vs geometric + photometric against the desired view."
RESPONSE_HELP = (
    "With --photometric: the devices' curves, gamma (assumed: 1 for the paper's blend, 2.2 for the physical "
    "one) or measured per sample from its views of grey levels (`projsynth response`) [default: gamma]."
)


@app.command(cls=Command)
def bench(
    data: Annotated[Path, typer.Option(help="Dataset directory (projsynth shards).", parser=input_path, metavar="DIR")],
    model: Annotated[
        list[Path] | None,
        typer.Option(
            help="Checkpoint, or `reference` (repeatable); default: the reference.", parser=input_path, metavar="CKPT"
        ),
    ] = None,
    baselines: Annotated[
        str | None,
        typer.Option(
            help="Comma list, or none (default: dis-fast,dis-medium,farneback,sift-ransac).",
            show_default=False,
            metavar="LIST",
        ),
    ] = None,
    equalize: Annotated[bool, typer.Option("--equalize", help="Equalise histograms for the baselines.")] = False,
    refine: Annotated[
        str,
        typer.Option(
            help="Geometric refinement after each model: on, off, or both (two rows: NAME refined, NAME-raw).",
            metavar="on|off|both",
        ),
    ] = "on",
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the report as JSON.", parser=output_path, metavar="FILE")
    ] = None,
    markdown: Annotated[
        Path | None, typer.Option(help="Write the Markdown tables.", parser=output_path, metavar="FILE")
    ] = None,
    fail_above: Annotated[
        list[str] | None,
        typer.Option(
            help="[NAME:]METRIC=VALUE gate on models (repeatable; NAME: that model only).",
            metavar="[NAME:]METRIC=VALUE",
        ),
    ] = None,
    limit: Annotated[int | None, typer.Option(help="Evaluate N samples spread over the dataset.")] = None,
    device: Device = None,
    precision: Precision = "fp32",
    backend: Backend = "auto",
    batch_size: Annotated[
        int, typer.Option(help="Samples per network call (pairs of one size are batched).", metavar="N")
    ] = 1,
    quality: Quality = DEFAULT_QUALITY,
    fast: Fast = False,
    photos: Annotated[bool, typer.Option("--photos", help=PHOTOS_HELP)] = False,
    compensation: Annotated[bool, typer.Option("--compensation", help=COMPENSATION_HELP)] = False,
    photometric: Annotated[bool, typer.Option("--photometric", help=PHOTOMETRIC_HELP)] = False,
    response: Annotated[str | None, typer.Option(help=RESPONSE_HELP, metavar="gamma|measured")] = None,
    sheet: Annotated[
        Path | None,
        typer.Option(
            help="With --compensation: contact sheet PNG of the first samples.", parser=output_path, metavar="FILE.png"
        ),
    ] = None,
    track: Annotated[
        bool,
        typer.Option(
            "--track",
            help="Sequences (gen --frames): also NAME+track rows, each frame from the previous one's flow; jitter.",
        ),
    ] = False,
    quiet: Quiet = False,
) -> None:
    """Benchmark models and baselines: EPE by bucket, role, family, condition; ms per pair."""
    from .evaluation import bench as lib
    from .evaluation import report as reporting
    from .evaluation.baselines import parse_baselines
    from .evaluation.methods import DEFAULT_BASELINES

    try:
        thresholds = [reporting.parse_threshold(spec) for spec in fail_above or []]
        if sheet is not None and (not compensation or sheet.suffix.lower() != ".png"):
            raise ProjregError(
                f"--sheet {sheet}: a PNG contact sheet of compensations; give --compensation and a name ending in .png"
            )
        lib.check_outputs(data, model or [], [("--json", json_out), ("--markdown", markdown), ("--sheet", sheet)])
        rows: list = []
        if baselines is None:
            names = list(DEFAULT_BASELINES)
        else:
            names = [] if baselines.strip().lower() == "none" else parse_baselines(baselines)
        _torch_threads()
        with Bar("bench", quiet, unit="pair") as bar:
            report = lib.run_bench(
                data,
                models=model or [],
                baselines=names,
                equalize=equalize,
                refine=refine,
                limit=limit,
                device=device,
                precision=precision,
                backend=backend,
                quality=resolve_quality(quality, fast),
                compensation=compensation,
                photometric=photometric,
                response=response,
                sheet=rows,
                progress=bar.done,
                track=track,
                batch_size=batch_size,
                photos=photos,
            )
        reporting.write_outputs(
            report, json_path=json_out, markdown_path=markdown, sheet=None if sheet is None else (sheet, rows)
        )  # all or nothing
        violations = reporting.check_thresholds(report, thresholds)
    except ProjregError as e:
        raise fail("projreg", e) from None
    if markdown is None:
        typer.echo(reporting.compact_table(report))
    if not model and report["reference_model"] is None:
        typer.echo("projreg: no shipped reference model yet; benchmarked the baselines only", err=True)
    for line in violations:
        typer.echo(f"projreg: fail-above: {line}", err=True)
    if violations:
        raise typer.Exit(1)


@app.command(cls=Command)
def predict(
    projected: Annotated[
        Path,
        typer.Option(help="Projected image, or a folder or video of them.", parser=input_path, metavar="IMG|DIR|VIDEO"),
    ],
    captured: Annotated[
        Path,
        typer.Option(
            help="Captured image, or a folder (same relative names as a --projected folder) or a video (frames "
            "paired in order with a --projected video or folder, or all with one --projected image).",
            parser=input_path,
            metavar="IMG|DIR|VIDEO",
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(help="Flow EXR file, or output folder (folders, videos).", parser=output_path, metavar="FILE|DIR"),
    ],
    viz: Annotated[
        Path | None,
        typer.Option(
            help="Colour-wheel PNG file, or folder (folders, videos).", parser=output_path, metavar="FILE|DIR"
        ),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option(
            help="Checkpoint, or `reference`; default: the shipped reference model.", parser=input_path, metavar="CKPT"
        ),
    ] = None,
    max_side: Annotated[int, typer.Option(help="Larger pairs are shrunk to this longer side for inference.")] = 1024,
    refine: Annotated[
        bool,
        typer.Option(
            help="Geometric refinement of the network's flow (docs/model.md; default on).", show_default=False
        ),
    ] = True,
    max_flow: MaxFlow = None,
    track: Annotated[
        bool,
        typer.Option(
            "--track",
            help="The frames of one sequence (folders in name order, videos): each from the previous one's flow.",
        ),
    ] = False,
    white: Annotated[
        Path | None,
        typer.Option(
            help="Camera photo of a full-white projection: the surface is divided out of every captured image "
            "(one photo for all pairs: a fixed rig).",
            parser=input_path,
            metavar="IMG",
        ),
    ] = None,
    black: Annotated[
        Path | None,
        typer.Option(
            help="With --white: camera photo of a full-black projection (removes the ambient light).",
            parser=input_path,
            metavar="IMG",
        ),
    ] = None,
    response: ResponseFile = None,
    device: Device = None,
    precision: Precision = "fp32",
    backend: Backend = "auto",
    batch_size: Annotated[
        int, typer.Option(help="Pairs per network call in folder mode (pairs of one size are batched).", metavar="N")
    ] = 1,
    quality: Quality = DEFAULT_QUALITY,
    fast: Fast = False,
    quiet: Quiet = False,
) -> None:
    """Predict the projected -> captured flow of real image pairs (EXR, optional PNG)."""
    from .inference.predict import predict as run_predict

    try:
        _torch_threads()
        with Bar("predict", quiet, unit="pair") as bar:
            written = run_predict(
                projected,
                captured,
                out,
                viz=viz,
                model=model,
                max_side=max_side,
                refine=refine,
                device=device,
                precision=precision,
                backend=backend,
                batch_size=batch_size,
                quality=resolve_quality(quality, fast),
                progress=bar.done,
                max_flow=max_flow,
                track=track,
                white=white,
                black=black,
                response=response,
            )
    except ProjregError as e:
        raise fail("projreg", e) from None
    for r in written:  # even with --quiet: a pair that could not be registered must not pass unnoticed
        if not r.registered:
            typer.echo(
                f"projreg: warning: {r.sample_id}: cannot be registered ({r.reason}); {r.out} claims no pixel "
                "(its flow is an unverified estimate; `projreg compensate` projects content as it is)",
                err=True,
            )
    if not quiet:
        typer.echo(f"{len(written)} flow file(s) written: {out}", err=True)


app.command(cls=Command)(compensate)
app.command(cls=Command)(warp)
app.command(cls=Command)(live)


def main() -> None:
    """The ``projreg`` console command (usage errors as one line, as in ``projsynth``)."""
    from projsynth.utils.console import run_console

    run_console(app, "projreg")


if __name__ == "__main__":
    main()
