"""Ablation of projreg.refine by configuration: what each stage adds, as the estimator runs it (docs/model.md).

    python bench/ablate_refine.py --data DIR [--model CKPT] [--every 4 | --limit N] [--side 256]

For every evaluated sample the network runs once (at ``--side``); each row is
then the refinement with one setting of :class:`projreg.refine.config.RefineConfig` changed from the
full one-stage search's (``SEARCH``: every start on every view), scored with the pooled EPE of
``projreg.evaluation.metrics`` (overall and the three magnitude buckets), the EPE on claimed pixels, the
claimed share and the median ms per pair of the refinement, beside the network alone and SIFT + RANSAC.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from projreg.evaluation.baselines import make_baseline
from projreg.evaluation.metrics import EPEAccumulator, sample_indices
from projreg.inference.runtime import TorchNetwork, flows_resized
from projreg.model.checkpoint import load_model, resolve_checkpoint
from projreg.refine.config import ACCURATE, BALANCED, FAST, SEARCH
from projreg.refine.refiner import GeometricRefiner
from projsynth.dataset.shards import ShardReader

BASE = SEARCH.with_sections(search={"workers": 1})  # timed on one thread: the rows compare work
ROWS = {
    "full search (every start, every view)": BASE,
    "- SIFT start": BASE.with_sections(search={"sift": False}),
    "- identity start": BASE.with_sections(search={"identity": False}),
    "- plain view": BASE.with_sections(images={"plain": False}),
    "- albedo view": BASE.with_sections(images={"albedo": False}),
    "- detail level": BASE.with_sections(surface={"detail": False}),
    "- growth": BASE.with_sections(search={"grow": False}),
    "- bridge": BASE.with_sections(confidence={"bridge": False}),
    "- re-alignment": BASE.with_sections(align={"realign": False}),
    "direct first stage, DIS below 60 %": BASE.with_sections(align={"direct": True}, search={"escalate_below": 0.6}),
    "balanced (second stage on evidence)": BALANCED.with_sections(search={"workers": 1}),
    "accurate (balanced's first stage, then the full search)": ACCURATE.with_sections(search={"workers": 1}),
    "fast": FAST.with_sections(search={"workers": 1}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", default="reference")
    ap.add_argument("--side", type=int, default=256, help="the network's longer side")
    ap.add_argument("--every", type=int, default=None, help="every N-th sample")
    ap.add_argument("--limit", type=int, default=None, help="N samples spread evenly (as projreg bench)")
    args = ap.parse_args()
    torch.set_num_threads(2)
    device = torch.device("cpu")
    net = TorchNetwork(load_model(resolve_checkpoint(args.model), device), device)
    refiners = {name: GeometricRefiner(cfg) for name, cfg in ROWS.items()}
    sift = make_baseline("sift-ransac")
    reader = ShardReader(args.data)
    n = len(reader)
    indices = list(range(0, n, args.every)) if args.every else sample_indices(n, args.limit)
    names = ["network alone", *ROWS, "sift-ransac (baseline)"]
    accs = {name: EPEAccumulator() for name in names}
    claimed = {name: [0.0, 0] for name in ROWS}  # claimed pixels' summed error, count
    valid_total, times = 0, {name: [] for name in ROWS}
    try:
        for k in indices:
            s = reader.read(k)
            flow = flows_resized(net, [(s["projected"], s["captured"])], args.side)[0]
            accs["network alone"].add(flow, s["flow"], s["valid"])
            accs["sift-ransac (baseline)"].add(sift.predict(s["projected"], s["captured"]), s["flow"], s["valid"])
            valid_total += int(s["valid"].sum())
            for name, refiner in refiners.items():
                t0 = time.perf_counter()
                pred = refiner.predict(s["projected"], s["captured"], flow)
                times[name].append(1000 * (time.perf_counter() - t0))
                accs[name].add(pred.flow, s["flow"], s["valid"])
                ok = pred.claimed & s["valid"]
                claimed[name][0] += float(np.linalg.norm(pred.flow - s["flow"], axis=-1)[ok].sum())
                claimed[name][1] += int(ok.sum())
    finally:
        reader.close()
    print(f"{args.data}: {len(indices)} of {n} samples, network at {args.side} px")
    print("| row | EPE / s0-10 / s10-40 / s40+ (px) | claimed EPE (px) | claimed % | ms per pair |")
    print("|---|---|---|---|---|")
    for name in names:
        r = accs[name].result()
        cells = " / ".join("-" if r[m] is None else f"{r[m]:.3f}" for m in ("epe", "s0-10", "s10-40", "s40+"))
        if name in ROWS:
            err, count = claimed[name]
            extra = f"{err / max(count, 1):.3f} | {100 * count / max(valid_total, 1):.1f} | "
            extra += f"{statistics.median(times[name]):.0f}"
        else:
            extra = "- | - | -"
        print(f"| {name} | {cells} | {extra} |")


if __name__ == "__main__":
    main()
