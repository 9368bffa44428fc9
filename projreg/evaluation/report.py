"""``projreg bench``'s report: the figures derived from the results (each model against the best
baseline of each pair), the Markdown tables, the ``--fail-above`` gates, and the files written."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.utils.files import write_atomic_all
from projsynth.utils.images import png_bytes

from ..errors import ProjregError
from .closedloop import sheet_header
from .metrics import BUCKETS, THRESHOLDS

GATED = ("epe", *BUCKETS, *(f"px{t}" for t in THRESHOLDS), "epe_claimed")  # epe_claimed: on the pixels claimed


TABLE_METRICS = (("EPE", "epe"), *((b, b) for b in BUCKETS))


RATIO_LIMIT = 1.5  # per pair, a model's EPE on its claimed pixels should be <= 1.5x the best baseline's


def versus_baselines(results: Sequence[dict], ratio_limit: float = RATIO_LIMIT) -> dict[str, dict]:
    """Each model against the best baseline *of each pair* (the pair-by-pair target), keyed by model name.

    Per pair, the best baseline is the one with the lowest EPE on the pixels it claims (a baseline
    that claims nothing on a pair, such as a failed ``sift-ransac``, does not compete there). A
    model's ratio on a pair is its EPE on the pixels it claims over that best EPE; pairs where it
    claims nothing (not registered) have no ratio. Returns, per model: ``baselines`` compared,
    ``pairs`` (with a baseline answer), ``rated`` (pairs with a ratio), ``worst_ratio`` and
    ``worst_ratio_id``, ``within`` (share of rated pairs with ratio <= ``ratio_limit``), ``claimed_mean``
    (mean per-pair share of valid pixels claimed, 0 for pairs claiming nothing), ``mean_pair_epe``
    (mean per-pair EPE on all valid pixels, claimed or not) and ``best_baseline`` /
    ``best_baseline_mean_pair_epe`` (the baseline with the lowest such mean). Empty without baselines.
    """
    base = [r for r in results if r["kind"] == "baseline"]
    if not base:
        return {}
    means = {r["name"]: _mean([p["epe"] for p in r["pairs"] if p["epe"] is not None]) for r in base}
    best_name = min(means, key=lambda n: math.inf if means[n] is None else means[n])
    out = {}
    for r in (r for r in results if r["kind"] == "model"):
        ratios, claims, epes, paired = [], [], [], 0
        for i, p in enumerate(r["pairs"]):
            best = [b["pairs"][i]["epe_claimed"] for b in base if b["pairs"][i]["epe_claimed"] is not None]
            if p["epe"] is None or not best:
                continue
            paired += 1
            claims.append(p["claimed"] or 0.0)
            epes.append(p["epe"])
            if p["epe_claimed"] is not None:
                ratios.append((p["epe_claimed"] / max(min(best), 1e-6), p["id"]))
        worst = max(ratios, default=(None, None))
        out[r["name"]] = {
            "baselines": [b["name"] for b in base],
            "pairs": paired,
            "rated": len(ratios),
            "worst_ratio": worst[0],
            "worst_ratio_id": worst[1],
            "within": _mean([float(q <= ratio_limit) for q, _ in ratios]),
            "claimed_mean": _mean(claims),
            "mean_pair_epe": _mean(epes),
            "best_baseline": best_name,
            "best_baseline_mean_pair_epe": means[best_name],
        }
    return out


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if len(values) else None


def parse_threshold(spec: str) -> tuple[str, float, str | None]:
    """``"[NAME:]METRIC=VALUE"`` -> ``(metric, value, name)``; METRIC one of ``GATED``; without NAME
    the threshold gates every model (``name`` None).

    Example:
        >>> parse_threshold("s40+=12.5")
        ('s40+', 12.5, None)
        >>> parse_threshold("reference-raw:epe=9")
        ('epe', 9.0, 'reference-raw')
    """
    target, sep, text = spec.partition("=")
    name, colon, metric = target.rpartition(":")
    metric, name = metric.strip(), name.strip() if colon else None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not sep or metric not in GATED or not math.isfinite(value):
        raise ProjregError(
            f"--fail-above: expected [NAME:]METRIC=VALUE with METRIC in {', '.join(GATED)} and a "
            f"finite VALUE, got {spec!r}"
        )
    if name == "":
        raise ProjregError(f"--fail-above: empty method name before ':' in {spec!r}")
    return metric, value, name


def check_thresholds(report: dict, thresholds: Sequence[tuple[str, float, str | None]]) -> list[str]:
    """One line per model result whose metric exceeds its threshold (baselines are never gated).

    A threshold with a name gates only that model, and naming a model the report lacks is an error.
    A metric that is null (no pixel behind it) passes. Gating a report without any model result
    is an error: the gate would pass without testing anything.
    """
    models = [r for r in report["results"] if r["kind"] == "model"]
    if thresholds and not models:
        raise ProjregError("--fail-above: no model was benchmarked (no --model and no shipped reference model)")
    names = {r["name"] for r in models}
    for _, _, name in thresholds:
        if name is not None and name not in names:
            raise ProjregError(
                f"--fail-above: no model named {name!r} in the report; models: {', '.join(sorted(names))}"
            )
    return [
        f"{r['name']}: {metric} {r[metric]:.4f} > {limit:g}"
        for r in models
        for metric, limit, name in thresholds
        if name in (None, r["name"]) and r[metric] is not None and r[metric] > limit
    ]


def _fmt(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "–" if value is None else f"{scale * value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def compact_table(report: dict) -> str:
    """One row per method: EPE, buckets, outlier rates in percent, ms per pair (and, with compensation,
    its PSNR and SSIM beside the EPE: where the two rankings disagree is what EPE cannot see; in
    tracking mode, the temporal jitter)."""
    comp = any("comp_psnr" in r for r in report["results"])
    jitter = any("jitter" in r for r in report["results"])
    header = ["method", "kind", "EPE", *BUCKETS, *(f"px{t} %" for t in THRESHOLDS), "ms/pair"]
    header += ["comp PSNR dB", "comp SSIM"] if comp else []
    header += ["jitter"] if jitter else []
    rows = [
        [
            r["name"],
            r["kind"],
            *(_fmt(r[k]) for k in ("epe", *BUCKETS)),
            *(_fmt(r[f"px{t}"], 100) for t in THRESHOLDS),
            _fmt(r["ms_per_pair"]),
        ]
        + ([_fmt(r.get("comp_psnr")), _fmt(r.get("comp_ssim"), digits=3)] if comp else [])
        + ([_fmt(r.get("jitter"), digits=3)] if jitter else [])
        for r in report["results"]
    ]
    return _table(header, rows)


def worst_case_table(report: dict) -> str:
    """One row per method: pooled EPE beside the per-pair distribution, then what it claims."""
    header = [
        "method",
        "EPE",
        "pair median",
        "pair p90",
        "worst pair",
        "worst id",
        "claimed %",
        "EPE claimed",
        "not registered",
    ]
    rows = [
        [
            r["name"],
            _fmt(r["epe"]),
            _fmt(r["pair_median"]),
            _fmt(r["pair_p90"]),
            _fmt(r["worst_epe"]),
            str(r["worst_id"]) if r["worst_id"] is not None else "–",
            _fmt(r["claimed"], 100),
            _fmt(r["epe_claimed"]),
            str(len(r["unregistered"])),
        ]
        for r in report["results"]
    ]
    return _table(header, rows)


def versus_table(report: dict) -> str:
    """One row per model: the pair-by-pair comparison with the best baseline (``versus_baselines``)."""
    header = [
        "model",
        "pairs rated",
        f"within {RATIO_LIMIT:g}x %",
        "worst ratio",
        "worst ratio id",
        "claimed %",
        "mean pair EPE",
        "best baseline",
        "its mean pair EPE",
    ]
    rows = [
        [
            name,
            f"{v['rated']} / {v['pairs']}",
            _fmt(v["within"], 100),
            _fmt(v["worst_ratio"]),
            str(v["worst_ratio_id"]) if v["worst_ratio_id"] is not None else "–",
            _fmt(v["claimed_mean"], 100),
            _fmt(v["mean_pair_epe"]),
            v["best_baseline"],
            _fmt(v["best_baseline_mean_pair_epe"]),
        ]
        for name, v in report["versus_baselines"].items()
    ]
    return _table(header, rows)


def to_markdown(report: dict) -> str:
    """The paper's Table 2 (method x metric rows, ``pair P / role`` columns + all), then ``compact_table``,
    ``worst_case_table`` and, with baselines and models, ``versus_table``."""
    ds = report["dataset"]
    flows = [r for r in report["results"] if r["kind"] != "none"]  # the uncompensated row has no flow
    columns = list(dict.fromkeys(k for r in flows for k in r["groups"]["pair_role"]))
    rows = [
        [r["name"], label, *(_fmt(r["groups"]["pair_role"].get(c, {}).get(key)) for c in columns), _fmt(r[key])]
        for r in flows
        for label, key in TABLE_METRICS
    ]
    size = "x".join(str(v) for v in ds["size"]) if ds["size"] else "?"
    ref = report["reference_model"]
    lines = [
        f"# projreg bench: {ds['path']}",
        "",
        f"{ds['evaluated']} of {ds['num_samples']} samples, {size}, split {ds['split']}, seed {ds['seed']}, "
        f"config {str(ds['config_hash'])[:12]}; reference model: {ref if ref else 'none'}.",
        "",
        _table(["method", "metric", *columns, "all"], rows),
        "",
        compact_table(report),
        "",
        "Per pair (EPE of each pair's valid pixels) and on the pixels each method claims:",
        "",
        worst_case_table(report),
        "",
    ]
    if report["versus_baselines"]:
        lines += ["Each model against the best baseline of each pair:", "", versus_table(report), ""]
    return "\n".join(lines)


def write_outputs(
    report: dict, *, json_path: Path | None, markdown_path: Path | None, sheet: tuple[Path, list] | None = None
) -> None:
    """The report as JSON and/or Markdown (and a contact sheet ``(path, rows)``), all or nothing (one
    unwritable path leaves none)."""
    files = [(Path(json_path), (json.dumps(report, indent=1) + "\n").encode())] if json_path else []
    if markdown_path:
        files.append((Path(markdown_path), to_markdown(report).encode()))
    if sheet is not None and sheet[1]:
        rows = sheet[1]
        picture = np.vstack([sheet_header(rows[0].shape[1] // 5), *rows])
        files.append((Path(sheet[0]), png_bytes(Path(sheet[0]), picture)))
    try:
        write_atomic_all(files, make_parents=True)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
