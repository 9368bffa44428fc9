"""Write docs/results.md from the measurement files under docs/results/ (``make results``).

Usage: python bench/results_page.py [--results DIR] [--out FILE] [--check]

Reads nothing but the files of ``--results`` (default docs/results): for each set of ``record.SETS``,
its ``SET.meta.json`` (written by bench/record.py) and the reports that record names; a set without
one is listed as not measured. The same files give the same bytes: no clock, no machine state, sets
in ``SETS`` order, groups in the order of the reports. ``--check`` writes nothing and exits 1 when
FILE is not what the files give.

No timing of the evaluation sets is shown (their ``ms_per_pair``, ``ms_mean``, ``predict_seconds``
and decode ``seconds`` come from a machine shared while they ran); only the ``latency`` set's are: its
``ms_per_pair`` beside its ratio to a peer of the same run and the load average, and its large pairs'
``predict_seconds`` beside the baselines' ``baseline_seconds``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from record import RESULTS, ROOT, SETS, ResultSet  # noqa: E402

OUT = Path("docs/results.md")
RATIO_LIMIT = 1.5  # projreg.evaluation.report.RATIO_LIMIT, issue 16's bound (read from the reports' own figures)

HEADER = """# Results

The current figures, one table per evaluation set. **Generated** by `make results`
(`bench/results_page.py`) from the measurement files in [results/](results/): do not edit by hand.
Each set is re-measured by one command, `make results-SET` (`bench/record.py SET`, which writes
`docs/results/SET.json` and `SET.meta.json`), and each table states the commands, the date, the
machine, the commit and the weights behind it. What was tried on the way, and older figures:
[history/](history/README.md).

How to read the tables (unless a table says otherwise):

* **Methods.** `reference`: the shipped network (`small`, `projreg/weights/reference.pt`) followed by
  the geometric refinement, what `projreg predict` and `projreg bench` run by default;
  `reference-raw`: the network alone; `dis-fast`, `dis-medium`, `farneback`, `sift-ransac`: OpenCV
  baselines (docs/projreg-cli.md). `+track`: the method tracking a sequence.
* **EPE** (px): end-point error pooled over every pixel with ground truth of the evaluated pairs;
  **per-pair mean**: the mean of the pairs' own EPEs; **s0-10 / s10-40 / s40+**: EPE over the pixels
  whose true displacement is under 10, 10-40 and over 40 px; **px1 / px3**: % of the pixels off by
  more than 1 / 3 px; **worst pair**: the largest per-pair EPE and the pair's id; **worst pair,
  claimed**: the largest EPE of a pair on the pixels the method claims there.
* **claimed %**: the share of the pixels with ground truth that a method says its flow holds on (the
  refinement's confidence; none of a pair it reports as not registered), and **EPE claimed** the EPE
  over those. `all`: the method claims every pixel (its EPE claimed is its EPE). **not registered**:
  pairs the method refused.
* **Against the best baseline of each pair** (issue 16): per pair, a model's EPE on the pixels it
  claims over the EPE of the best baseline on the same pair; rated pairs are those where the model
  claims something.
* Figures have three significant digits. No timings in these tables: the sets are measured on the
  machine at hand, often shared with other work; latency has its own section, measured on an idle
  machine.
"""


def num(x: float | None, sig: int = 3) -> str:
    """``sig`` significant digits (``22.7``, ``0.464``, ``115``), ``–`` for a missing figure."""
    if x is None:
        return "–"
    if x == 0 or not math.isfinite(x):
        return f"{x:g}"
    return f"{x:.{max(0, sig - 1 - math.floor(math.log10(abs(x))))}f}"


def pct(x: float | None) -> str:
    """A share (0..1) as a percentage with one decimal."""
    return "–" if x is None else f"{100 * x:.1f}"


def para(text: str) -> str:
    """A paragraph wrapped at 100 columns (words and hyphenated names kept whole)."""
    return textwrap.fill(text, 100, break_long_words=False, break_on_hyphens=False)


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def load(results: Path, name: str) -> dict | None:
    path = results / name
    return json.loads(path.read_text()) if path.exists() else None


def conditions(meta: dict) -> str:
    """The paragraph every table of a set shares: when, where, which code and weights."""
    m, v = meta["machine"], meta["versions"]
    code = f"commit `{meta['commit']}`"
    if meta["code_commit"] != meta["commit"]:
        code += f" (`projsynth/` and `projreg/` as of `{meta['code_commit']}`)"
    if meta["dirty"]:
        code += ", **with uncommitted changes**"
    threads = m["threads"]
    memory = f", {num(m['memory_gib'])} GiB" if m.get("memory_gib") else ""
    return para(
        f"Measured {meta['date'].replace('T', ' ')[:16]} UTC (the set took {num(meta['wall_s'] / 60, 2)} min) on "
        f"{m['cpu']}, {m['cores']} cores{memory}, {threads} thread{'s' if threads != 1 else ''} for torch, "
        f"numba and OpenCV, load average {m['load_average_start'][0]:.2f} at the start (1 min); {code}; "
        f"reference weights sha256 `{meta['weights']['sha256']}`; python {v['python']}, torch {v['torch']}, "
        f"numpy {v['numpy']}, OpenCV {v['opencv']}."
    )


def commands(meta: dict) -> str:
    return "```\n" + "\n".join(meta["commands"]) + "\n```"


def dataset_line(report: dict) -> str:
    ds = report["dataset"]
    size = " x ".join(str(v) for v in ds["size"]) if ds.get("size") else "?"
    camera = ds.get("camera_size")
    if camera and camera != ds["size"]:
        size += f" (camera {' x '.join(str(v) for v in camera)})"
    spread = ", spread evenly over the set" if ds["evaluated"] < ds["num_samples"] else ""
    return f"{ds['evaluated']} of {ds['num_samples']} samples{spread}; {size}; split {ds['split']}, seed {ds['seed']}."


def _claims(r: dict) -> tuple[str, str]:
    if not r["refined"] and r["claimed"] == 1.0:
        return "all", "–"
    return pct(r["claimed"]), num(r["epe_claimed"])


def _worst(value: float | None, ident: str | None) -> str:
    return "–" if value is None else f"{num(value)} (`{ident}`)"


def _worst_claimed(r: dict) -> str:
    """The largest EPE of a pair on its claimed pixels and the pair (issue 57: a claim's worst case)."""
    rated = [p for p in r.get("pairs", []) if p.get("epe_claimed") is not None]
    if (not r["refined"] and r["claimed"] == 1.0) or not rated:
        return "–"
    worst = max(rated, key=lambda p: p["epe_claimed"])
    return _worst(worst["epe_claimed"], worst["id"])


def main_table(report: dict) -> str:
    """Every method with a flow: EPE pooled and per pair, buckets, outlier rates, claims, worst pair."""
    header = ["method", "EPE", "per-pair mean", "s0-10", "s10-40", "s40+", "px1 %", "px3 %", "claimed %"]
    header += ["EPE claimed", "worst pair", "worst pair, claimed", "not registered"]
    rows = [
        [
            f"`{r['name']}`",
            *(num(r[k]) for k in ("epe", "image_epe", "s0-10", "s10-40", "s40+")),
            pct(r["px1"]),
            pct(r["px3"]),
            *_claims(r),
            _worst(r["worst_epe"], r["worst_id"]),
            _worst_claimed(r),
            str(len(r["unregistered"])),
        ]
        for r in report["results"]
        if r["kind"] != "none"
    ]
    return table(header, rows)


def versus(report: dict) -> str:
    """Each model against the best baseline of each pair (``versus_baselines`` of the report)."""
    header = ["model", "pairs rated", f"within {RATIO_LIMIT:g}x %", "worst ratio", "claimed, mean per pair %"]
    header += ["mean per-pair EPE", "best baseline: its mean per-pair EPE"]
    rows = [
        [
            f"`{name}`",
            f"{v['rated']} of {v['pairs']}",
            pct(v["within"]),
            _worst(v["worst_ratio"], v["worst_ratio_id"]),
            pct(v["claimed_mean"]),
            num(v["mean_pair_epe"]),
            f"`{v['best_baseline']}`: {num(v['best_baseline_mean_pair_epe'])}",
        ]
        for name, v in report["versus_baselines"].items()
    ]
    return table(header, rows)


COMPENSATION = (
    ("content on surface % (min)", "comp_shown"),
    ("comp PSNR dB", "comp_psnr"),
    ("comp SSIM", "comp_ssim"),
    ("claimed only: comp PSNR", "comp_psnr_claimed"),
    ("geo PSNR", "geo_psnr"),
    ("photo PSNR", "photo_psnr"),
    ("geo SSIM", "geo_ssim"),
    ("photo SSIM", "photo_ssim"),
    ("geo ΔE00", "geo_de2000"),
    ("photo ΔE00", "photo_de2000"),
)


def compensation(report: dict) -> str:
    cols = [(label, key) for label, key in COMPENSATION if any(key in r for r in report["results"])]

    def cell(r: dict, key: str) -> str:
        if key == "comp_shown":
            return "–" if r.get(key) is None else f"{pct(r[key])} ({pct(r['comp_shown_min'])})"
        return num(r.get(key))

    rows = [[f"`{r['name']}`", num(r["epe"]), *(cell(r, key) for _, key in cols)] for r in report["results"]]
    return table(["method", "EPE", *(label for label, _ in cols)], rows)


def reliability(report: dict) -> str:
    """Per refined method and confidence band: the share of the registered pairs' valid pixels in the
    band and the shares of those within 1 px and 3 px (projreg/evaluation/reliability.py)."""
    rows = [
        [f"`{r['name']}`", b["band"], pct(b["share"]), pct(b["within1"]), pct(b["within3"])]
        for r in report["results"]
        for b in r.get("reliability", [])
    ]
    return table(["method", "confidence", "pixels %", "within 1 px %", "within 3 px %"], rows)


def tracking(report: dict) -> str:
    def frames(r: dict) -> str:
        t = r.get("tracking")
        return "–" if t is None else f"{t['full']} / {t['tracked']} / {t['lost']}"

    rows = [[f"`{r['name']}`", num(r.get("jitter")), frames(r)] for r in report["results"]]
    return table(["method", "jitter px", "frames full / tracked / lost"], rows)


def bench_run(report: dict) -> list[str]:
    out = [para(f"Data: {dataset_line(report)}"), "", main_table(report), ""]
    if report["versus_baselines"]:
        out += ["Against the best baseline of each pair:", "", versus(report), ""]
    if any("comp_psnr" in r for r in report["results"]):
        out += ["What the camera sees of each method's compensation:", "", compensation(report), ""]
    if any("reliability" in r for r in report["results"]):
        out += ["What a confidence level means (registered pairs' valid pixels):", "", reliability(report), ""]
    if any("jitter" in r for r in report["results"]):
        out += ["Over time:", "", tracking(report), ""]
    return out


def span(rows: list[dict], key: str) -> str:
    """The range of ``key`` over ``rows``: ``min-max``."""
    return f"{num(min(r[key] for r in rows))}-{num(max(r[key] for r in rows))}"


def scene(s: dict) -> str:
    return f"transform {s['tid']} ({s['family']}, {s['condition']})"


def decode_run(report: dict) -> list[str]:
    out = [
        f"Projector {report['size'].replace('x', ' x ')}, camera {report['camera'].replace('x', ' x ')}, every "
        f"{report['every']}th transform, seed {report['seed']}.",
        "",
    ]
    header = ["condition", "scenes", "coverage % (min)", "median px", "mean px", "p95 px", "max px"]
    header += ["valid where truth is not"]
    for kind, k in report["kinds"].items():
        rows = [
            [
                g["condition"],
                str(g["scenes"]),
                f"{pct(g['coverage'])} ({pct(g['coverage_min'])})",
                *(num(g[s]) for s in ("median", "mean", "p95", "max")),
                str(g["wrong"]),
            ]
            for g in k["by_condition"]
        ]
        fam = k["by_family"]
        scenes = [s for s in k["scenes"] if s["p95"] is not None]
        worst = max(scenes, key=lambda s: s["p95"])
        low = min(k["scenes"], key=lambda s: s["coverage"])
        out += [
            f"**{kind}**:",
            "",
            table(header, rows),
            "",
            para(
                f"Over the {len(fam)} families: median {span(fam, 'median')} px, p95 {span(fam, 'p95')} px. "
                f"Worst scene p95: {scene(worst)} {num(worst['p95'])} px; lowest coverage: {scene(low)} "
                f"{pct(low['coverage'])} %."
            ),
            "",
        ]
    return out


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def external_run(report: dict) -> list[str]:
    pairs, s = report["pairs"], report["summary"]
    names = [k[: -len("_on_claimed")] for k in pairs[0] if k.endswith("_on_claimed")]
    rated = [p for p in pairs if p["epe_claimed"] is not None]

    def row(label: str, all_key: str, claimed_key: str | None) -> list[str]:
        worst = max(pairs, key=lambda p: p[all_key])
        on_claimed = _mean([p[claimed_key] for p in rated if p[claimed_key] is not None]) if claimed_key else None
        return [label, num(_mean([p[all_key] for p in pairs])), num(on_claimed), _worst(worst[all_key], worst["pair"])]

    rows = [row("`projreg predict`", "epe", "epe_claimed")]
    rows += [row(f"`{n}`", n, f"{n}_on_claimed") for n in names]
    rows.append(row("best baseline of each pair", "best_baseline", None))
    header = ["method", "per-pair mean EPE", "per-pair mean EPE on the claimed pixels", "worst pair"]
    size = s["size"].replace("x", " x ")
    worst = "no pair rated" if s["worst_pair"] is None else f"worst ratio {num(s['worst_ratio'])}, `{s['worst_pair']}`"
    far = max(rated, key=lambda p: p["epe_claimed"]) if rated else None
    far = "" if far is None else f" Worst EPE on a pair's claimed pixels: {num(far['epe_claimed'])} (`{far['pair']}`)."
    return [
        f"Data: {s['pairs']} pairs, {size}, seed {s['seed']}.",
        "",
        table(header, rows),
        "",
        para(
            f"`projreg predict` claims {pct(s['claimed_mean'])} % of the pixels with truth on average; on "
            f"{s['rated']} of {s['pairs']} pairs it claims something, and on {pct(s['within_1_5'])} % of those its "
            f"EPE on the claimed pixels is within {RATIO_LIMIT:g}x the better baseline's on the same pixels ({worst}). "
            "Not registered: "
            f'{", ".join(s["not_registered"]) or "none"}. "On the claimed pixels": the pairs where the pipeline '
            "claims something, each method on the pipeline's claimed pixels." + far
        ),
        "",
    ]


def latency_run(report: dict, meta: dict) -> list[str]:
    rows_in = [r for r in report["results"] if r.get("ms_per_pair") is not None]
    peer = meta.get("peer") or next((r["name"] for r in rows_in if r["kind"] == "baseline"), rows_in[0]["name"])
    peers = [peer] + [name for name in ("sift-ransac",) if name != peer and any(r["name"] == name for r in rows_in)]
    base = {p: next(r["ms_per_pair"] for r in rows_in if r["name"] == p) for p in peers}
    rows = [
        [f"`{r['name']}`", num(r["ms_per_pair"]), *(num(r["ms_per_pair"] / base[p]) for p in peers)] for r in rows_in
    ]
    start, end = (", ".join(f"{x:.2f}" for x in meta["machine"][k]) for k in ("load_average_start", "load_average_end"))
    return [
        para(f"Data: {dataset_line(report)} Load average at the start {start} (1, 5, 15 min), at the end {end}."),
        "",
        table(["method", "ms per pair (median)", *(f"x `{p}`" for p in peers)], rows),
        "",
    ]


def large_pairs_run(report: dict) -> list[str]:
    """A latency set's ``bench/external_rig.py`` report: ``projreg predict``'s seconds per pair (one folder
    call) beside each baseline's on the same pairs, and what the pipeline claimed there."""
    s, pairs = report["summary"], report["pairs"]
    n, per_pair = s["pairs"], s["predict_seconds"] / s["pairs"]
    peers = {name: total / n for name, total in s["baseline_seconds"].items()}
    rows = [["`projreg predict` (one call)", num(per_pair), *(num(per_pair / t) for t in peers.values())]]
    rows += [[f"`{name}`", num(t), *(num(t / u) for u in peers.values())] for name, t in peers.items()]
    claimed = [p for p in pairs if p["epe_claimed"] is not None]
    worst = max(claimed, key=lambda p: p["epe_claimed"]) if claimed else None
    epes = sorted(p["epe"] for p in pairs)
    median = (epes[(n - 1) // 2] + epes[n // 2]) / 2
    return [
        para(f"Data: {n} pairs, {s['size'].replace('x', ' x ')}, seed {s['seed']} (`bench/external_rig.py`)."),
        "",
        table(["method", "s per pair", *(f"x `{name}`" for name in peers)], rows),
        "",
        para(
            f"On these pairs `projreg predict` claims {pct(s['claimed_mean'])} % of the pixels with truth on "
            f"average; median pair EPE {num(median)} px; worst EPE on a pair's claimed pixels "
            + ("–" if worst is None else f"{num(worst['epe_claimed'])} px (`{worst['pair']}`)")
            + f"; not registered: {', '.join(s['not_registered']) or 'none'}. The baselines' times are their "
            "computation alone, in process; `predict`'s includes its start-up and files."
        ),
        "",
    ]


def warp_run(report: dict) -> list[str]:
    """``bench/bench_warp.py``: each warp file applied as a show tool applies it, against ``compensate``."""
    rows = []
    for r in report["rows"]:
        mesh = "–" if "error_mean_px" not in r else f"{num(r['error_mean_px'])} / {num(r['error_max_px'])}"
        rows.append(
            [r["file"], num(r["grey_mean"]), str(r["grey_max"]), pct(r["covered"]), str(r["beyond"]), mesh]
            + [num(r["kib_median"])]
        )
    header = ["file", "grey levels off, mean", "max", "covered %", "beyond", "mesh error mean / max (px)", "KiB"]
    return [
        para(
            f"Data: {len(report['pairs'])} pairs of `{report['data']}`, every one registered by `projreg predict`; "
            "differences from `projreg compensate`'s image where both show content (0..255), the share of its "
            "pixels with content the file covers, pixels with content it leaves dark that the file lights "
            "(`beyond`), the meshes' interpolation error in camera pixels, the median file size (the flow EXR: "
            f"{num(report['flow_kib_median'])} KiB)."
        ),
        "",
        table(header, rows),
        "",
    ]


def live_run(report: dict) -> list[str]:
    """``bench/bench_live.py``: the live loop on sequences played in real time, with and without prediction."""
    pooled, seqs = report["pooled"], report["sequences"]
    runs = [(q["sequence"], q["live"], q["live"]["shown_epe"], q["predicted"]["shown_epe"]) for q in seqs]
    runs.append(("**all**", pooled, pooled["shown_epe"], pooled["shown_epe_predicted"]))
    rows = [
        [
            name,
            num(live["fps"]),
            f"{num(live['latency_ms']['median'])} / {num(live['latency_ms']['p95'])}",
            f"{live['frames_in']} / {live['registered']} / {live['dropped']}",
            f"{num(live['epe_tracked'])} / {num(live['epe_per_frame'])} ({num(live['ratio'])})",
            f"{num(plain)} / {num(predicted)}",
        ]
        for name, live, plain, predicted in runs
    ]
    load = ", ".join(f"{x:.2f}" for x in report["load_average"]["before"])
    header = ["sequence", "registered frames/s", "latency median / p95 (ms)", "in / registered / dropped"]
    header += ["EPE tracked / per frame (ratio)", "shown EPE: no prediction / predicted"]
    return [
        para(
            f"Data: {len(report['sequences'])} sequences of {report['data']['frames']} frames at "
            f"{report['data']['size']}, played at {report['data']['fps']} fps, `--quality {report['quality']}`; "
            f"load average before {load} (1, 5, 15 min)."
        ),
        "",
        table(header, rows),
        "",
    ]


def missing(rs: ResultSet) -> list[str]:
    if rs.kind == "live":
        return [para(f"Not measured yet: `make results-{rs.name} THREADS=2` on an idle machine writes it."), ""]
    if rs.kind == "latency":
        return [
            para(
                "Not measured yet. The sets above ran on a machine shared with other work, so their timings are "
                f"not shown. `{RESULTS / 'latency.json'}` and `latency.meta.json`, written by `make results-latency "
                "THREADS=N` on an idle machine, will hold the latency; this section then shows each method's "
                "milliseconds per pair, "
                "its ratio to a peer of the same run and the load average."
            ),
            "",
        ]
    return [f"Not measured at present: `make results-{rs.name}` writes its files under `{RESULTS}/`.", ""]


def section(rs: ResultSet, results: Path) -> list[str]:
    out = [f"## {rs.title}", "", para(rs.about), ""]
    meta = load(results, f"{rs.name}.meta.json")
    if meta is None:
        return out + missing(rs)
    out += [conditions(meta), "", commands(meta), ""]
    for run in meta["runs"]:
        report = load(results, run["report"])
        if len(meta["runs"]) > 1:
            out += [f"### {run['label'][:1].upper()}{run['label'][1:]}", ""]
        if report is None:
            out += [f"`{RESULTS / run['report']}` is missing: run `make results-{rs.name}`.", ""]
        elif rs.kind == "decode":
            out += decode_run(report)
        elif rs.kind == "external":
            out += external_run(report)
        elif rs.kind == "warp":
            out += warp_run(report)
        elif rs.kind == "live":
            out += live_run(report)
        elif rs.kind == "latency":
            out += latency_run(report, meta) if "results" in report else large_pairs_run(report)
        else:
            out += bench_run(report)
    return out


def anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    kept = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def page(results: Path) -> str:
    """The whole page from the files under ``results``."""
    measured = {s.name for s in SETS if (results / f"{s.name}.meta.json").exists()}
    contents = [f"* [{s.title}](#{anchor(s.title)}){'' if s.name in measured else ' (not measured)'}" for s in SETS]
    lines = [HEADER, "\n".join(contents), ""]
    for rs in SETS:
        lines += section(rs, results)
    return "\n".join(lines).rstrip("\n") + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=ROOT / RESULTS)
    ap.add_argument("--out", type=Path, default=ROOT / OUT)
    ap.add_argument("--check", action="store_true", help="exit 1 if --out differs from what the files give")
    args = ap.parse_args()
    text = page(args.results)
    if args.check:
        if not args.out.exists() or args.out.read_text() != text:
            raise SystemExit(f"{args.out} is not what {args.results} gives: run make results")
        return
    args.out.write_text(text)


if __name__ == "__main__":
    main()
