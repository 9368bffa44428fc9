"""The ``projsynth`` command line: parse, call one library function, map errors to one line + exit 2."""

from __future__ import annotations

import json
import sys
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import cv2
import typer
from tqdm import tqdm
from typer.core import TyperCommand

from . import ProjsynthError
from .capture import capture as capture_scene
from .dataset import parse_size, resolve_plan
from .decode import decode_folder
from .export import export as export_samples
from .export import preview as preview_sheet
from .generate import default_shard_size, generate, merge
from .structured import make_set, parse_grid, read_patterns, write_patterns
from .transforms import load_table, table_to_toml
from .verify import inspect as inspect_dataset
from .verify import verify as verify_dataset

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Reproducible projector-camera pairs with exact ground-truth flow.")  # fmt: skip

cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # our own errors name the file

Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


def output_path(text: str) -> Path:
    """The value of an output option; an empty one (an unset shell variable) is refused, where a plain
    ``Path`` would read it as the current directory and write there."""
    if not text.strip():
        raise typer.BadParameter("empty; give a path to write to")
    return Path(text)


def _fail(e: Exception) -> typer.Exit:
    typer.echo(f"projsynth: error: {e}", err=True)
    return typer.Exit(2)


def _bar(total: int | None, desc: str, quiet: bool) -> tqdm:
    return tqdm(total=total, desc=desc, unit="sample", disable=quiet, file=sys.stderr, leave=False)


def _set_total(bar: tqdm, n: int) -> None:
    bar.total = n
    bar.refresh()


SPLIT_HELP = "train, val or test (disjoint source images), or all (every image: a held-out folder)."


@app.command()
def gen(
    out: Annotated[Path, typer.Option(help="Dataset directory (created; re-running resumes).", parser=output_path)],
    natural: Annotated[Path | None, typer.Option(help="Folder of natural images (recursive).")] = None,
    generated: Annotated[Path | None, typer.Option(help="Folder of generated/illustration images.")] = None,
    pairs: Annotated[int | None, typer.Option(help="Image pairs (default: 4 built-in, or all in the split).")] = None,
    size: Annotated[str, typer.Option(help="Image size HxW.")] = "384x512",
    seed: Annotated[int, typer.Option(help="Seed of every random draw.")] = 0,
    split: Annotated[str, typer.Option(help=SPLIT_HELP)] = "train",
    transforms: Annotated[str | None, typer.Option(help="Transform ids, e.g. 0-15 or 0,5,9 (default all).")] = None,
    table: Annotated[Path | None, typer.Option(help="TOML transform table replacing the built-in one.")] = None,
    shard_size: Annotated[int | None, typer.Option(help="Samples per shard (default 64, rounded down to whole "
                                                        "sequences).", show_default=False)] = None,
    shards: Annotated[str | None, typer.Option(help="Only these shards, e.g. 40-79 (job arrays).")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes.")] = 1,
    blend: Annotated[str, typer.Option(help="Photometric model: paper or physical.")] = "paper",
    frames: Annotated[int, typer.Option(help="Frames per sequence: > 1 moves the rig (docs/format.md).")] = 1,
    motion: Annotated[str | None, typer.Option(help="Sequences: hover, gust, vibration or orbit (default "
                                                    "hover).", show_default=False)] = None,
    quiet: Quiet = False,
) -> None:
    """Generate shards of (projected, captured, flow) samples."""
    try:
        plan = resolve_plan(size=parse_size(size), seed=seed, split=split, pairs=pairs, transforms=transforms,
                            blend=blend, table_path=table, natural=natural, generated=generated, frames=frames,
                            motion=motion)  # fmt: skip
        shard_size = default_shard_size(plan.frames) if shard_size is None else shard_size
        for line in plan.skipped:
            typer.echo(f"projsynth: warning: skipped {line}", err=True)
        with _bar(plan.num_samples, "gen", quiet) as bar:  # --shards: sized to the selected shards
            result = generate(plan, out, shard_size=shard_size, shards=shards, workers=workers, progress=bar.update,
                              progress_total=partial(_set_total, bar))  # fmt: skip
    except ProjsynthError as e:
        raise _fail(e) from None
    if not quiet:
        state = "complete, manifest written" if result.manifest else "manifest pending (run `projsynth merge`)"
        typer.echo(f"{out}: {len(result.written)} shards written, {len(result.skipped)} already done, "
                   f"{result.num_shards} in the plan; {state}", err=True)  # fmt: skip


@app.command("merge")
def merge_cmd(root: Annotated[Path, typer.Argument(help="Dataset directory.")]) -> None:
    """Write manifest.json once every shard exists (after a job array)."""
    try:
        manifest = merge(root)
    except ProjsynthError as e:
        raise _fail(e) from None
    typer.echo(f"{root}: manifest of {manifest['num_samples']} samples in {len(manifest['shards'])} shards", err=True)


@app.command()
def verify(root: Annotated[Path, typer.Argument(help="Dataset directory.")], quiet: Quiet = False) -> None:
    """Check schema, hashes, NaN/Inf and flow/valid consistency; exit 1 naming each bad shard."""
    try:
        with _bar(None, "verify", quiet) as bar:
            problems = verify_dataset(root, progress=bar.update)
    except ProjsynthError as e:
        raise _fail(e) from None
    for p in problems:
        typer.echo(f"projsynth: verify: {p}", err=True)
    if problems:
        raise typer.Exit(1)
    if not quiet:
        typer.echo(f"{root}: OK", err=True)


@app.command()
def inspect(
    root: Annotated[Path, typer.Argument(help="Dataset directory.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Counts, flow-magnitude histogram and valid-pixel share per bucket and family."""
    try:
        report = inspect_dataset(root)
    except ProjsynthError as e:
        raise _fail(e) from None
    if as_json:
        typer.echo(json.dumps(report, indent=1))
        return
    typer.echo(f"{report['dataset']}: {report['config']}")
    typer.echo(f"{'family':18s} {'samples':>7s} {'valid':>6s} {'s0-10':>6s} {'s10-40':>6s} {'s40+':>6s}")
    for name, r in [*report["families"].items(), ("TOTAL", report["total"])]:
        b = r["bucket_share"]
        typer.echo(f"{name:18s} {r['samples']:7d} {r['valid_share']:6.1%} {b['s0-10']:6.1%} "
                   f"{b['s10-40']:6.1%} {b['s40+']:6.1%}")  # fmt: skip


@app.command()
def export(
    root: Annotated[Path, typer.Argument(help="Dataset directory.")],
    out: Annotated[Path, typer.Option(help="Output folder.", parser=output_path)],
    limit: Annotated[int | None, typer.Option(help="Export only the first N samples.")] = None,
    quiet: Quiet = False,
) -> None:
    """Write PNGs, the flow .exr bytes unchanged, Middlebury .flo and a colour visualisation."""
    try:
        with _bar(None, "export", quiet) as bar:
            n = export_samples(root, out, limit, progress=bar.update, progress_total=partial(_set_total, bar))
    except ProjsynthError as e:
        raise _fail(e) from None
    if not quiet:
        typer.echo(f"{out}: {n} samples exported", err=True)


@app.command()
def preview(
    root: Annotated[Path, typer.Argument(help="Dataset directory.")],
    out: Annotated[Path, typer.Option(help="PNG to write.")],
    count: Annotated[int, typer.Option(help="Rows (samples spread over the dataset).")] = 8,
) -> None:
    """Contact sheet: projected | captured | flow colour | valid."""
    try:
        n = preview_sheet(root, out, count)
    except ProjsynthError as e:
        raise _fail(e) from None
    typer.echo(f"{out}: {n} samples", err=True)


@app.command("transforms")
def transforms_cmd(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    as_toml: Annotated[bool, typer.Option("--toml", help="Print TOML (editable, for --table).")] = False,
    table: Annotated[Path | None, typer.Option(help="Show this TOML table instead of the built-in one.")] = None,
) -> None:
    """Print the transform table (160 configurations by default)."""
    try:
        if as_json and as_toml:
            raise ProjsynthError("--json and --toml exclude each other; pick one output format")
        tab = load_table(table)
    except ProjsynthError as e:
        raise _fail(e) from None
    if as_toml:
        typer.echo(table_to_toml(tab))
    elif as_json:
        rows = [{"id": c.id, "name": c.name, "family": c.family, "severity": c.severity,
                 "condition": c.condition, "geometry": c.geometry, "photometry": c.photometry}
                for c in tab.configs]  # fmt: skip
        typer.echo(json.dumps({"version": tab.version, "transforms": rows}, indent=1))
    else:
        typer.echo(f"table {tab.version}: {len(tab)} configurations")
        for c in tab.configs:
            g = ", ".join(f"{k}={a:g}..{b:g}" for k, (a, b) in c.geometry.items() if k not in ("fov_deg",))
            typer.echo(f"{c.id:4d} {c.name:30s} {g}")


@app.command()
def patterns(
    kind: Annotated[str, typer.Option(help="graycode (dense, sub-pixel) or dots (the paper's 11-image protocol).")],
    size: Annotated[str, typer.Option(help="Projector frame HxW.")],
    out: Annotated[Path, typer.Option(help="Folder for the PNGs (NN-<name>.png) and patterns.json.")],
    grid: Annotated[str, typer.Option(help="dots: dot grid ROWSxCOLS.")] = "20x20",
    period: Annotated[int, typer.Option(help="graycode: fringe period in projector px (multiple of 4).")] = 16,
    shifts: Annotated[int, typer.Option(help="graycode: phase shifts per axis.")] = 8,
) -> None:
    """Write a structured-light pattern set to project, in order (docs/real-rig.md)."""
    try:
        files = write_patterns(make_set(kind, parse_size(size), parse_grid(grid), period, shifts), out)
    except ProjsynthError as e:
        raise _fail(e) from None
    typer.echo(f"{out}: {len(files) - 1} patterns and patterns.json", err=True)


@app.command()
def capture(
    patterns_dir: Annotated[Path, typer.Option("--patterns", help="Folder written by `projsynth patterns`.")],
    out: Annotated[Path, typer.Option(help="Folder for the photos, truth.exr and capture.json.")],
    transform: Annotated[int, typer.Option(help="Transform id of the scene (see `projsynth transforms`).")],
    seed: Annotated[int, typer.Option(help="Seed of the scene, photometry and noise.")] = 0,
    camera_size: Annotated[str | None, typer.Option(help="Camera frame HxW (default: the projector's).")] = None,
    content: Annotated[list[Path] | None, typer.Option(help="Picture to photograph too (repeatable).")] = None,
    background: Annotated[Path | None, typer.Option(help="Surface as the camera sees it (default: built-in).")] = None,
    blend: Annotated[str, typer.Option(help="Photometric model: physical (gamma, response) or paper.")] = "physical",
    table: Annotated[Path | None, typer.Option(help="TOML transform table replacing the built-in one.")] = None,
) -> None:
    """Virtual rig: photograph the patterns (and pictures) through one simulated scene, with exact truth."""
    try:
        cam = None if camera_size is None else parse_size(camera_size, "--camera-size")
        scene = {"table": load_table(table), "transform": transform, "seed": seed, "camera_size": cam}
        pictures = {"contents": content or [], "background": background, "blend": blend}
        record = capture_scene(read_patterns(patterns_dir), out, **scene, **pictures)
    except ProjsynthError as e:
        raise _fail(e) from None
    photos, pictures = len(record["patterns"]["order"]), len(record["contents"])
    share = record["valid_share"]
    typer.echo(f"{out}: {photos} photos, {pictures} pictures, truth.exr ({share:.1%} of projector px valid)", err=True)


PAIR_HELP = "A picture and its photo from the same rig pose (repeatable): OUT becomes a dataset of them."


class _PairCommand(TyperCommand):
    """``--pair PROJECTED CAPTURED``, repeatable: two values per occurrence (Typer has no list of tuples)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            if param.name == "pair":
                param.nargs, param.multiple = 2, True


@app.command(cls=_PairCommand)
def decode(
    patterns_dir: Annotated[Path, typer.Option("--patterns", help="Folder written by `projsynth patterns`.")],
    captures: Annotated[Path, typer.Option(help="Folder of the photos, named as the patterns (any extension).")],
    out: Annotated[Path, typer.Option(help="Folder for correspondence.exr (and the dataset with --pair).")],
    pair: Annotated[list[Any] | None, typer.Option(metavar="PROJECTED CAPTURED", help=PAIR_HELP)] = None,
) -> None:
    """Decode pattern photos into the projector -> camera correspondence (and a dataset of pairs)."""
    try:
        summary = decode_folder(patterns_dir, captures, out, [(Path(a), Path(b)) for a, b in pair or []])
    except ProjsynthError as e:
        raise _fail(e) from None
    typer.echo(f"{out}: {summary}", err=True)


def run_console(application: typer.Typer, prog: str) -> None:
    """Run a Typer app as a console command whose usage errors are one line too.

    Typer prints a bad option value, a missing option or an unknown command as a framed, multi-line
    box; here it is ``PROG: error: MESSAGE; see `PROG COMMAND --help``` and exit 2, like every other
    error of these tools.
    """
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


def main() -> None:
    """The ``projsynth`` console command."""
    run_console(app, "projsynth")


if __name__ == "__main__":
    main()
