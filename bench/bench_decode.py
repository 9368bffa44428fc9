"""Structured-light decode accuracy and speed on the virtual rig, against the simulator's exact truth.

Usage: python bench/bench_decode.py [--size 480x640] [--camera 600x800] [--every 4] [--seed 0]

For every ``--every``-th transform of the built-in table: photograph the graycode and the dots
patterns through that scene (``projsynth.structured.capture``), decode, and compare with the exact forward map.
Prints one Markdown row per condition and per family (pooled), the worst transform of each metric,
and the decode time per set. Figures go to docs/benchmarks.md.
"""

import argparse
import time

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


def rows(results: list[dict], key: str) -> list[str]:
    out = []
    for group in dict.fromkeys(r[key] for r in results):
        rs = [r for r in results if r[key] == group]
        err = np.concatenate([r["err"] for r in rs])
        cov = [r["coverage"] for r in rs]
        out.append(
            f"| {group} | {len(rs)} | {np.mean(cov):.1%} (min {np.min(cov):.1%}) | {np.median(err):.3f} | "
            f"{err.mean():.3f} | {np.percentile(err, 95):.3f} | {err.max():.2f} | {sum(r['wrong'] for r in rs)} |"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="480x640")
    ap.add_argument("--camera", default="600x800")
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    size, camera = parse_size(args.size), parse_size(args.camera, "--camera")
    ids = range(0, len(builtin_table()), args.every)
    for kind in ("graycode", "dots"):
        results = [measure(kind, tid, size, camera, args.seed) for tid in ids]
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


if __name__ == "__main__":
    main()
