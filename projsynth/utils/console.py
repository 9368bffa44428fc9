"""The console plumbing both command lines share: help that reads at 80 columns, one-line errors and
usage errors (exit 2), progress bars on stderr, and the options every command names the same way.

The library never prints or exits; a command calls it and maps its error to :func:`fail`.
"""

from __future__ import annotations

import os
import sys
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import typer
from tqdm import tqdm
from typer.core import TyperCommand

from .cores import use_available_cores


class Command(TyperCommand):
    """Help that reads at 80 columns: click's plain layout (rich's table cuts long option names and
    defaults) and every value shown as the docs name it (``DIR``, ``FILE``, ``N``), never Typer's
    ``<list[Path]>`` or ``<bool>``. A value without an explicit ``metavar`` is named by its type; an
    argument shows as its metavar alone (``DIR``, not Typer's ``{root}`` and ``<path>``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            if param.metavar is None and not getattr(param, "is_flag", False):
                element = param.bare_type().removeprefix("list[").removesuffix("]")
                param.metavar = _METAVARS.get(element, element.upper())
            if param.param_type_name == "argument":
                param._usage_display_name = partial(str, param.metavar)
                param.display_type_rich = lambda ctx: None


_METAVARS = {"int": "N", "float": "X", "str": "TEXT", "Path": "PATH"}


PLAIN_HELP = {
    "rich_markup_mode": None,
    "add_completion": False,
    "no_args_is_help": True,
    "pretty_exceptions_enable": False,
}


MaxFlow = Annotated[
    float | None,
    typer.Option(
        help="Flow colours saturate at this magnitude in px, the "
        "same for every picture (default: each picture's largest).",
        metavar="PX",
    ),
]


def output_path(text: str) -> Path:
    """The value of an output option; an empty one (an unset shell variable) is refused, where a plain
    ``Path`` would read it as the current directory and write there."""
    if not text.strip():
        raise typer.BadParameter("empty; give a path to write to")
    return Path(text)


def input_path(text: str) -> Path:
    """The value of an input option; an empty one (an unset shell variable) is refused, where a plain
    ``Path`` would read it as the current directory and blame another option."""
    if not text.strip():
        raise typer.BadParameter("empty; give the path to read")
    return Path(text)


class Bar:
    """A tqdm bar on stderr, drawn only when the work starts (its first ``total`` or ``update``).

    A command whose input is refused before any work (a missing dataset, a bad option) prints its one
    error line with no empty bar before it. ``--quiet``, and every torchrun rank but 0, draw none.
    """

    def __init__(self, desc: str, quiet: bool, unit: str = "sample", total: int | None = None):
        self.kwargs = {
            "desc": desc,
            "unit": unit,
            "disable": quiet or not is_rank0(),
            "file": sys.stderr,
            "leave": False,
            "dynamic_ncols": True,
            "total": total,
        }
        self.bar: tqdm | None = None

    def _get(self) -> tqdm:
        if self.bar is None:
            self.bar = tqdm(**self.kwargs)
        return self.bar

    def total(self, n: int) -> None:
        """Set the total (the bar is drawn from here on)."""
        if self.bar is None:
            self.kwargs["total"] = n
        bar = self._get()
        bar.total = n
        bar.refresh()

    def update(self, n: int = 1) -> None:
        self._get().update(n)

    def done(self, done: int, total: int) -> None:
        """``(done, total)`` progress, as the library's ``progress`` callbacks report it."""
        if self.bar is None:
            self.kwargs["total"] = total
        bar = self._get()
        bar.total = total
        bar.update(done - bar.n)

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()


def is_rank0() -> bool:
    """False in every torchrun worker but rank 0: only rank 0 draws bars and prints summaries."""
    return os.environ.get("RANK", "0") == "0"


# OpenMP workers (torch's, numba's) that sleep when idle instead of spinning: on a machine another job
# shares, spinning threads steal the cores their peers wait for. Measured on the 2-core VM, the reference
# network's forward pass at 384 x 512: idle 657 ms spinning, 746 ms passive (+14 %); beside another torch
# job 1.85-2.35 s spinning, 1.12-1.51 s passive (docs/design.md, "Threads on a shared machine"). A user's
# own OMP_WAIT_POLICY wins.
WAIT_POLICY = "PASSIVE"


def run_console(application: typer.Typer, prog: str) -> None:
    """Run a Typer app as a console command whose usage errors are one line too.

    Typer prints a bad option value, a missing option or an unknown command as a framed, multi-line
    box; here it is ``PROG: error: MESSAGE; see `PROG COMMAND --help``` and exit 2, like every other
    error of these tools.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)  # before torch's OpenMP runtime loads
    use_available_cores()
    try:
        code = application(prog_name=prog, standalone_mode=False)
    except typer.Abort:
        typer.echo(f"{prog}: aborted", err=True)
        code = 1
    except typer.TyperException as e:  # click's usage errors
        ctx = getattr(e, "ctx", None)
        where = ctx.command_path if ctx is not None else prog
        message = " ".join(e.format_message().split()).rstrip(".")
        typer.echo(f"{prog}: error: {message}; see `{where} --help`", err=True)
        code = getattr(e, "exit_code", 2)
    sys.exit(code if isinstance(code, int) else 0)


Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


def fail(prog: str, e: Exception) -> typer.Exit:
    """The library's error ``e`` as the one line ``PROG: error: MESSAGE`` on stderr, and exit 2."""
    typer.echo(f"{prog}: error: {e}", err=True)
    return typer.Exit(2)
