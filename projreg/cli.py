"""The ``projreg`` command line: parse, call one library function, map errors to one line + exit 2."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from . import ProjregError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Train, benchmark and apply the SSJM projector-camera registration network.")  # fmt: skip


@app.callback()
def main() -> None:
    """Train, benchmark and apply the SSJM projector-camera registration network."""


def _fail(e: Exception) -> typer.Exit:
    typer.echo(f"projreg: error: {e}", err=True)
    return typer.Exit(2)


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


@app.command()
def train(
    data: Annotated[list[Path], typer.Option(help="Training dataset directory (repeat for several).")],
    out: Annotated[Path, typer.Option(help="Run directory.")],
    val: Annotated[list[Path] | None, typer.Option(help="Validation dataset directory (repeatable).")] = None,
    model: Annotated[str, typer.Option(help="small or base.")] = "small",
    no_ssjm: Annotated[bool, typer.Option("--no-ssjm", help="Build the ablation without SSJM.")] = False,
    steps: Annotated[int, typer.Option(help="Optimiser steps (paper: 15000).")] = 15000,
    batch_size: Annotated[int, typer.Option(help="Samples per step (per process under torchrun).")] = 8,
    lr: Annotated[float, typer.Option(help="Peak learning rate of the OneCycle schedule.")] = 4e-4,
    seed: Annotated[int, typer.Option(help="Seed of initialisation, sample order and augmentation.")] = 0,
    crop: Annotated[str, typer.Option(help="Training crop HxW, or none for full frames.")] = "256x320",
    workers: Annotated[int, typer.Option(help="DataLoader worker processes.")] = 2,
    val_every: Annotated[int, typer.Option(help="Validate every N steps.")] = 500,
    ckpt_every: Annotated[int, typer.Option(help="Write last.pt every N steps.")] = 100,
    log_every: Annotated[int, typer.Option(help="Log a metrics row every N steps.")] = 10,
    amp: Annotated[bool, typer.Option(help="bf16 autocast (CUDA only).")] = False,
    compile: Annotated[bool, typer.Option("--compile", help="torch.compile the model.")] = False,
    resume: Annotated[bool, typer.Option(help="Continue RUN/checkpoints/last.pt exactly.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Train the registration network on projsynth shards."""
    from .train import TrainConfig
    from .train import train as run_training

    try:
        cfg = TrainConfig(data=[str(p) for p in data], out=str(out), val=[str(p) for p in val or []], model=model,
                          use_ssjm=not no_ssjm, steps=steps, batch_size=batch_size, lr=lr, seed=seed,
                          workers=workers, crop=_parse_crop(crop), val_every=val_every, ckpt_every=ckpt_every,
                          log_every=log_every, amp=amp, compile=compile)  # fmt: skip
        with tqdm(total=steps, desc="train", unit="step", disable=quiet, file=sys.stderr, leave=False) as bar:
            def progress(step: int, loss: float) -> None:
                bar.n = step
                bar.set_postfix(loss=f"{loss:.3f}", refresh=False)
                bar.refresh()

            summary = run_training(cfg, resume=resume, progress=progress)
    except ProjregError as e:
        raise _fail(e) from None
    if not quiet:
        typer.echo(f"{out}: step {summary['step']}, loss {summary['loss']:.4f}, best val EPE {summary['best_epe']}",
                   err=True)  # fmt: skip


if __name__ == "__main__":
    app()
