"""The ``projsynth`` command line: parse, call one library function, map errors to one line + exit 2."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import cv2
import typer

from .dataset.export import export as export_samples
from .dataset.export import preview as preview_sheet
from .dataset.generate import default_shard_size, generate, merge
from .dataset.plan import parse_size, resolve_plan
from .dataset.transforms import load_table, table_to_toml
from .dataset.verify import inspect as inspect_dataset
from .dataset.verify import verify as verify_dataset
from .errors import ProjsynthError
from .structured.capture import capture as capture_scene
from .structured.decode import decode_folder
from .structured.patterns import make_set, parse_grid, read_patterns, write_patterns
from .structured.response import fit_folder
from .utils.console import PLAIN_HELP, Bar, Command, MaxFlow, Quiet, fail, input_path, output_path, run_console

app = typer.Typer(**PLAIN_HELP, help="Reproducible projector-camera pairs with exact ground-truth flow.")

cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # our own errors name the file


def _status(line: str) -> None:
    typer.echo(f"projsynth: {line}", err=True)


SPLIT_HELP = "train, val or test (disjoint source images), or all (every image: a held-out folder)."


@app.command(cls=Command)
def gen(
    out: Annotated[
        Path, typer.Option(help="Dataset directory (created; re-running resumes).", parser=output_path, metavar="DIR")
    ],
    natural: Annotated[
        Path | None, typer.Option(help="Folder of natural images (recursive).", parser=input_path, metavar="DIR")
    ] = None,
    generated: Annotated[
        Path | None, typer.Option(help="Folder of generated/illustration images.", parser=input_path, metavar="DIR")
    ] = None,
    pairs: Annotated[int | None, typer.Option(help="Image pairs (default: 4 built-in, or all in the split).")] = None,
    size: Annotated[str, typer.Option(help="Image size HxW.", metavar="HxW")] = "384x512",
    seed: Annotated[int, typer.Option(help="Seed of every random draw.", metavar="S")] = 0,
    split: Annotated[str, typer.Option(help=SPLIT_HELP, metavar="SPLIT")] = "train",
    transforms: Annotated[
        str | None, typer.Option(help="Transform ids, e.g. 0-15 or 0,5,9 (default all).", metavar="SPEC")
    ] = None,
    table: Annotated[
        Path | None,
        typer.Option(help="TOML transform table replacing the built-in one.", parser=input_path, metavar="FILE.toml"),
    ] = None,
    shard_size: Annotated[
        int | None,
        typer.Option(
            help="Samples per shard (default 64, rounded down to whole sequences).", show_default=False, metavar="N"
        ),
    ] = None,
    shards: Annotated[
        str | None, typer.Option(help="Only these shards: 40-79, or 3/16 (array task 3 of 16).", metavar="A-B|K/N")
    ] = None,
    workers: Annotated[int, typer.Option(help="Worker processes.", metavar="K")] = 1,
    blend: Annotated[
        str, typer.Option(help="Photometric model: paper or physical.", metavar="paper|physical")
    ] = "paper",
    frames: Annotated[
        int, typer.Option(help="Frames per sequence: > 1 moves the rig (docs/format.md).", metavar="N")
    ] = 1,
    motion: Annotated[
        str | None,
        typer.Option(
            help="Sequences: hover, gust, vibration or orbit (default hover).", show_default=False, metavar="PRESET"
        ),
    ] = None,
    quiet: Quiet = False,
) -> None:
    """Generate shards of (projected, captured, flow) samples."""
    try:
        plan = resolve_plan(
            size=parse_size(size),
            seed=seed,
            split=split,
            pairs=pairs,
            transforms=transforms,
            blend=blend,
            table_path=table,
            natural=natural,
            generated=generated,
            frames=frames,
            motion=motion,
        )
        shard_size = default_shard_size(plan.frames) if shard_size is None else shard_size
        for line in plan.skipped:
            typer.echo(f"projsynth: warning: skipped {line}", err=True)
        with Bar("gen", quiet) as bar:  # --shards: sized to the selected shards
            result = generate(
                plan,
                out,
                shard_size=shard_size,
                shards=shards,
                workers=workers,
                progress=bar.update,
                progress_total=bar.total,
                status=_status,
            )
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    if not quiet:
        state = "complete, manifest written" if result.manifest else "manifest pending (run `projsynth merge`)"
        typer.echo(
            f"{out}: {len(result.written)} shards written, {len(result.skipped)} already done, "
            f"{result.num_shards} in the plan; {state}",
            err=True,
        )


@app.command("merge", cls=Command)
def merge_cmd(
    root: Annotated[Path, typer.Argument(help="Dataset directory.", parser=input_path, metavar="DIR")],
) -> None:
    """Write manifest.json once every shard exists (after a job array)."""
    try:
        manifest = merge(root)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    typer.echo(f"{root}: manifest of {manifest['num_samples']} samples in {len(manifest['shards'])} shards", err=True)


@app.command(cls=Command)
def verify(
    root: Annotated[Path, typer.Argument(help="Dataset directory.", parser=input_path, metavar="DIR")],
    quiet: Quiet = False,
) -> None:
    """Check schema, hashes, NaN/Inf and flow/valid consistency; exit 1 naming each bad shard."""
    try:
        with Bar("verify", quiet) as bar:
            problems = verify_dataset(root, progress=bar.update, progress_total=bar.total)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    for p in problems:
        typer.echo(f"projsynth: verify: {p}", err=True)
    if problems:
        raise typer.Exit(1)
    if not quiet:
        typer.echo(f"{root}: OK", err=True)


@app.command(cls=Command)
def inspect(
    root: Annotated[Path, typer.Argument(help="Dataset directory.", parser=input_path, metavar="DIR")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    quiet: Quiet = False,
) -> None:
    """Counts, flow-magnitude histogram and valid-pixel share per bucket and family."""
    try:
        with Bar("inspect", quiet) as bar:
            report = inspect_dataset(root, progress=bar.update, progress_total=bar.total)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    if as_json:
        typer.echo(json.dumps(report, indent=1))
        return
    for line in inspect_table(report):
        typer.echo(line)


def inspect_table(report: dict) -> list[str]:
    """``inspect``'s report as text: the dataset, then per family and in total the valid share, the
    share of valid pixels per bucket, and the magnitude histogram (share of valid pixels per bin)."""
    c = report["config"]
    size = "x".join(map(str, c.get("size", []))) or "?"
    about = [f"{report['total']['samples']} samples", f"size {size}"] + [
        f"{k} {c[k]}" for k in ("seed", "split", "pairs", "blend", "table_version") if k in c
    ]
    lines = [f"{report['dataset']}: " + ", ".join(about), ""]
    rows = [*report["families"].items(), ("TOTAL", report["total"])]
    n = max(len(name) for name, _ in rows)
    lines.append(f"{'family':{n}s} {'samples':>7s} {'valid':>6s}  {'s0-10':>6s} {'s10-40':>6s} {'s40+':>6s}")
    for name, r in rows:
        b = r["bucket_share"]
        lines.append(
            f"{name:{n}s} {r['samples']:7d} {r['valid_share']:6.1%}  {b['s0-10']:6.1%} "
            f"{b['s10-40']:6.1%} {b['s40+']:6.1%}"
        )
    edges = report["histogram_edges_px"]
    bins = [f"{a}-{b}" if b is not None else f"{a}+" for a, b in zip(edges[:-1], edges[1:], strict=True)]
    lines += ["", "flow magnitude histogram (px), share of valid pixels:"]
    lines.append(f"{'family':{n}s} " + " ".join(f"{b:>6s}" for b in bins))
    for name, r in rows:
        total = max(sum(r["histogram"]), 1)
        lines.append(f"{name:{n}s} " + " ".join(f"{h / total:6.1%}" for h in r["histogram"]))
    total = max(sum(report["total"]["histogram"]), 1)
    lines += ["", "all samples:"]
    for b, h in zip(bins, report["total"]["histogram"], strict=True):
        lines.append(f"{b:>7s} px {'#' * round(40 * h / total):40s} {h / total:6.1%}")
    return lines


@app.command(cls=Command)
def export(
    root: Annotated[Path, typer.Argument(help="Dataset directory.", parser=input_path, metavar="DIR")],
    out: Annotated[Path, typer.Option(help="Output folder.", parser=output_path, metavar="DIR")],
    limit: Annotated[int | None, typer.Option(help="Export only the first N samples.")] = None,
    max_flow: MaxFlow = None,
    quiet: Quiet = False,
) -> None:
    """Write PNGs, the flow .exr bytes unchanged, Middlebury .flo and a colour visualisation."""
    try:
        with Bar("export", quiet) as bar:
            n = export_samples(root, out, limit, progress=bar.update, progress_total=bar.total, max_flow=max_flow)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    if not quiet:
        typer.echo(f"{out}: {n} samples exported", err=True)


@app.command(cls=Command)
def preview(
    root: Annotated[Path, typer.Argument(help="Dataset directory.", parser=input_path, metavar="DIR")],
    out: Annotated[Path, typer.Option(help="PNG to write.", parser=output_path, metavar="FILE.png")],
    count: Annotated[int, typer.Option(help="Rows (samples spread over the dataset).")] = 8,
    max_flow: MaxFlow = None,
) -> None:
    """Contact sheet: projected | captured | flow colour | valid, labelled, with the wheel's legend."""
    try:
        n = preview_sheet(root, out, count, max_flow)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    typer.echo(f"{out}: {n} samples", err=True)


@app.command("transforms", cls=Command)
def transforms_cmd(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    as_toml: Annotated[bool, typer.Option("--toml", help="Print TOML (editable, for --table).")] = False,
    table: Annotated[
        Path | None,
        typer.Option(help="Show this TOML table instead of the built-in one.", parser=input_path, metavar="FILE.toml"),
    ] = None,
) -> None:
    """Print the transform table (160 configurations by default)."""
    try:
        if as_json and as_toml:
            raise ProjsynthError("--json and --toml exclude each other; pick one output format")
        tab = load_table(table)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    if as_toml:
        typer.echo(table_to_toml(tab))
    elif as_json:
        rows = [
            {
                "id": c.id,
                "name": c.name,
                "family": c.family,
                "severity": c.severity,
                "condition": c.condition,
                "geometry": c.geometry,
                "photometry": c.photometry,
            }
            for c in tab.configs
        ]
        typer.echo(json.dumps({"version": tab.version, "transforms": rows}, indent=1))
    else:
        typer.echo(f"table {tab.version}: {len(tab)} configurations")
        for c in tab.configs:
            g = ", ".join(f"{k}={a:g}..{b:g}" for k, (a, b) in c.geometry.items() if k not in ("fov_deg",))
            typer.echo(f"{c.id:4d} {c.name:30s} {g}")


@app.command(cls=Command)
def patterns(
    kind: Annotated[
        str,
        typer.Option(
            help="graycode (dense, sub-pixel), dots (the paper's 11-image protocol), opencv-graycode "
            "(OpenCV's GrayCodePattern layout) or response (grey levels: `projsynth response`).",
            metavar="KIND",
        ),
    ],
    size: Annotated[str, typer.Option(help="Projector frame HxW.", metavar="HxW")],
    out: Annotated[
        Path,
        typer.Option(help="Folder for the PNGs (NN-<name>.png) and patterns.json.", parser=output_path, metavar="DIR"),
    ],
    grid: Annotated[
        str | None, typer.Option(help="dots: dot grid ROWSxCOLS [default: 20x20].", metavar="ROWSxCOLS")
    ] = None,
    period: Annotated[
        int | None,
        typer.Option(help="graycode: fringe period in projector px, a multiple of 4 in 8..1024 [default: 16]."),
    ] = None,
    shifts: Annotated[int | None, typer.Option(help="graycode: phase shifts per axis, 3..64 [default: 8].")] = None,
    levels: Annotated[
        int | None, typer.Option(help="response: grey levels from black to white, 5..256 [default: 17].")
    ] = None,
) -> None:
    """Write a structured-light pattern set to project, in order (docs/real-rig.md)."""
    try:
        grid_size = None if grid is None else parse_grid(grid)
        pattern_set = make_set(kind, parse_size(size), grid_size, period, shifts, levels)
        files = write_patterns(pattern_set, out)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    typer.echo(f"{out}: {len(files) - 1} patterns and patterns.json", err=True)


@app.command(cls=Command)
def capture(
    patterns_dir: Annotated[
        Path,
        typer.Option("--patterns", help="Folder written by `projsynth patterns`.", parser=input_path, metavar="DIR"),
    ],
    out: Annotated[
        Path,
        typer.Option(help="Folder for the photos, truth.exr and capture.json.", parser=output_path, metavar="DIR"),
    ],
    transform: Annotated[
        int, typer.Option(help="Transform id of the scene (see `projsynth transforms`).", metavar="ID")
    ],
    seed: Annotated[int, typer.Option(help="Seed of the scene, photometry and noise.", metavar="S")] = 0,
    camera_size: Annotated[
        str | None, typer.Option(help="Camera frame HxW (default: the projector's).", metavar="HxW")
    ] = None,
    content: Annotated[
        list[Path] | None,
        typer.Option(help="Picture to photograph too (repeatable).", parser=input_path, metavar="IMG"),
    ] = None,
    background: Annotated[
        Path | None,
        typer.Option(help="Surface as the camera sees it (default: built-in).", parser=input_path, metavar="IMG"),
    ] = None,
    blend: Annotated[
        str, typer.Option(help="Photometric model: physical (gamma, response) or paper.", metavar="physical|paper")
    ] = "physical",
    table: Annotated[
        Path | None,
        typer.Option(help="TOML transform table replacing the built-in one.", parser=input_path, metavar="FILE.toml"),
    ] = None,
) -> None:
    """Virtual rig: photograph the patterns (and pictures) through one simulated scene, with exact truth."""
    try:
        cam = None if camera_size is None else parse_size(camera_size, "--camera-size")
        scene = {"table": load_table(table), "transform": transform, "seed": seed, "camera_size": cam}
        pictures = {"contents": content or [], "background": background, "blend": blend}
        record = capture_scene(read_patterns(patterns_dir), out, **scene, **pictures, patterns_dir=patterns_dir)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    photos, pictures = len(record["patterns"]["order"]), len(record["contents"])
    share = record["valid_share"]
    typer.echo(f"{out}: {photos} photos, {pictures} pictures, truth.exr ({share:.1%} of projector px valid)", err=True)


PAIR_HELP = "A picture and its photo from the same rig pose (repeatable): OUT becomes a dataset of them."


class _PairCommand(Command):
    """``--pair PROJECTED CAPTURED``, repeatable: two values per occurrence (Typer has no list of tuples)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            if param.name == "pair":
                param.nargs, param.multiple = 2, True


@app.command(cls=_PairCommand)
def decode(
    captures: Annotated[
        Path,
        typer.Option(
            help="Folder of the photos: named as the patterns (any extension), or in OpenCV's order by name.",
            parser=input_path,
            metavar="DIR",
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            help="Folder for correspondence.exr (and the dataset with --pair).", parser=output_path, metavar="DIR"
        ),
    ],
    patterns_dir: Annotated[
        Path | None,
        typer.Option("--patterns", help="Folder written by `projsynth patterns`.", parser=input_path, metavar="DIR"),
    ] = None,
    layout: Annotated[
        str,
        typer.Option(
            help="projsynth (photos named as --patterns) or opencv (GrayCodePattern's order; needs --projector).",
            metavar="projsynth|opencv",
        ),
    ] = "projsynth",
    projector: Annotated[
        str | None, typer.Option(help="--layout opencv: the projector's frame HxW (height first).", metavar="HxW")
    ] = None,
    pair: Annotated[list[Any] | None, typer.Option(metavar="PROJECTED CAPTURED", help=PAIR_HELP)] = None,
) -> None:
    """Decode pattern photos into the projector -> camera correspondence (and a dataset of pairs)."""
    try:
        size = None if projector is None else parse_size(projector, "--projector")
        if any(not text.strip() for two in pair or [] for text in two):  # '' would be read as the current folder
            raise ProjsynthError("--pair: empty; give the paths of a picture and of its photo")
        pairs = [(Path(a), Path(b)) for a, b in pair or []]
        summary = decode_folder(patterns_dir, captures, out, pairs, layout=layout, projector=size)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    typer.echo(f"{out}: {summary}", err=True)


@app.command(cls=Command)
def response(
    patterns_dir: Annotated[
        Path,
        typer.Option(
            "--patterns",
            help="Folder written by `projsynth patterns --kind response`.",
            parser=input_path,
            metavar="DIR",
        ),
    ],
    captures: Annotated[
        Path, typer.Option(help="Folder of the photos, named as the patterns.", parser=input_path, metavar="DIR")
    ],
    out: Annotated[Path, typer.Option(help="Response file to write (JSON).", parser=output_path, metavar="FILE.json")],
) -> None:
    """Measure the camera's and the projector's response curves from photos of grey levels (docs/real-rig.md)."""
    try:
        line = fit_folder(patterns_dir, captures, out)
    except ProjsynthError as e:
        raise fail("projsynth", e) from None
    typer.echo(f"{out}: {line}", err=True)


def main() -> None:
    """The ``projsynth`` console command."""
    run_console(app, "projsynth")


if __name__ == "__main__":
    main()
