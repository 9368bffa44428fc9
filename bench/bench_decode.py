"""Structured-light decode accuracy and speed on the virtual rig, against the simulator's exact truth.

Usage: python bench/bench_decode.py [--size 480x640] [--camera 600x800] [--every 4] [--seed 0]
    [--kinds graycode,dots] [--json F]

For every ``--every``-th transform of the built-in table: photograph each of the ``--kinds`` pattern sets
(``graycode``, ``dots``, ``opencv-graycode``) through that scene (``projsynth.structured.capture``), decode,
and compare with the exact forward map.
Prints one Markdown row per condition and per family (pooled), the worst transform of each metric,
and the decode time per set. ``--json F`` also writes them: per pattern set (``kinds``), the rows
``by_condition`` and ``by_family`` and one record per transform (``scenes``); docs/results.md is
made from that file (``bench/record.py decode``).
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

from projsynth.dataset.plan import parse_size
from projsynth.dataset.transforms import builtin_table
from projsynth.sim.render import ground_truth
from projsynth.sim.scene import MISS, OCCLUDED, OUT_OF_FRAME, forward, pixel_grid
from projsynth.structured.capture import make_rig, shoot
from projsynth.structured.decode import decode
from projsynth.structured.patterns import dot_centres, make_set


def measure(kind: str, tid: int, size: tuple[int, int], camera: tuple[int, int], seed: int) -> dict:
    patterns = make_set(kind, size)
    rig = make_rig(builtin_table(), tid, seed, size, camera)
    photos = np.stack([shoot(rig, img, seed, i) for i, img in enumerate(patterns.images())])
    gray = photos.mean(axis=3, dtype=np.float32) / 255
    t0 = time.perf_counter()
    result = decode(patterns, gray)
    seconds = time.perf_counter() - t0
    _, valid, reason = ground_truth(rig.scene)
    grid = pixel_grid(*size)
    exact = (forward(rig.scene, grid).uv - grid).T.reshape(*size, 2)  # exact also where valid is 0 (edge band)
    if kind == "dots":
        c = dot_centres(patterns)
        target, got = valid[c[:, 1], c[:, 0]], result.valid[c[:, 1], c[:, 0]]
        err = np.hypot(*(result.flow - exact)[c[:, 1], c[:, 0]][got].T)
    else:
        target, got = valid, result.valid
        err = np.hypot(*(result.flow - exact)[got].T)
    wrong = int((result.valid & ((reason & (MISS | OUT_OF_FRAME | OCCLUDED)) > 0)).sum())
    return {
        "tid": tid,
        "condition": rig.params["transform"]["condition"],
        "family": rig.params["transform"]["family"],
        "coverage": float((got & target).sum() / max(target.sum(), 1)),
        "err": err,
        "wrong": wrong,
        "seconds": seconds,
    }


def group_stats(results: list[dict], key: str) -> list[dict]:
    """Per group of ``key`` (in order of first appearance): scenes, coverage (mean, min) and the pooled
    error's median, mean, p95 and max, and the pixels decoded where the truth has none."""
    out = []
    for group in dict.fromkeys(r[key] for r in results):
        rs = [r for r in results if r[key] == group]
        err = np.concatenate([r["err"] for r in rs])
        cov = [r["coverage"] for r in rs]
        out.append(
            {
                key: group,
                "scenes": len(rs),
                "coverage": float(np.mean(cov)),
                "coverage_min": float(np.min(cov)),
                "median": float(np.median(err)),
                "mean": float(err.mean()),
                "p95": float(np.percentile(err, 95)),
                "max": float(err.max()),
                "wrong": sum(r["wrong"] for r in rs),
            }
        )
    return out


def rows(results: list[dict], key: str) -> list[str]:
    return [
        f"| {g[key]} | {g['scenes']} | {g['coverage']:.1%} (min {g['coverage_min']:.1%}) | {g['median']:.3f} | "
        f"{g['mean']:.3f} | {g['p95']:.3f} | {g['max']:.2f} | {g['wrong']} |"
        for g in group_stats(results, key)
    ]


def scene_record(r: dict) -> dict:
    """One transform's figures for ``--json`` (its per-pixel errors summarised; None where none was decoded)."""
    err = r["err"]
    out = {k: r[k] for k in ("tid", "condition", "family", "coverage", "wrong", "seconds")}
    for name, value in (("median", np.median), ("p95", lambda e: np.percentile(e, 95)), ("max", np.max)):
        out[name] = float(value(err)) if err.size else None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="480x640")
    ap.add_argument("--camera", default="600x800")
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default="graycode,dots", help="pattern sets, comma-separated (also opencv-graycode)")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON to this file")
    args = ap.parse_args()
    size, camera = parse_size(args.size), parse_size(args.camera, "--camera")
    ids = range(0, len(builtin_table()), args.every)
    record = {"size": args.size, "camera": args.camera, "every": args.every, "seed": args.seed, "kinds": {}}
    for kind in args.kinds.split(","):
        results = [measure(kind, tid, size, camera, args.seed) for tid in ids]
        record["kinds"][kind] = {
            "scenes": [scene_record(r) for r in results],
            "seconds_median": float(np.median([r["seconds"] for r in results])),
            **{f"by_{key}": group_stats(results, key) for key in ("condition", "family")},
        }
        print(
            f"\n{kind}: projector {args.size}, camera {args.camera}, {len(results)} transforms (every "
            f"{args.every}th), seed {args.seed}; decode {np.median([r['seconds'] for r in results]):.2f} s median"
        )
        head = "| {} | scenes | coverage | median px | mean px | p95 px | max px | valid where truth is not |"
        for key in ("condition", "family"):
            print("\n" + head.format(key) + "\n|---|---|---|---|---|---|---|---|")
            print("\n".join(rows(results, key)))
        worst = max(results, key=lambda r: np.percentile(r["err"], 95) if r["err"].size else 0)
        low = min(results, key=lambda r: r["coverage"])
        print(
            f"\nworst p95: transform {worst['tid']} ({worst['family']}, {worst['condition']}) "
            f"{np.percentile(worst['err'], 95):.3f} px; lowest coverage: transform {low['tid']} "
            f"({low['family']}, {low['condition']}) {low['coverage']:.1%}"
        )
    if args.json:
        args.json.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
