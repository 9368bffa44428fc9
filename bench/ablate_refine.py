"""Ablation of projreg.refine: what each step adds to the network's flow (docs/model.md's table).

    python bench/ablate_refine.py --data DIR [--model CKPT] [--every 4 | --limit N]

For every evaluated sample the network runs once; the stages are then computed from its flow with
the refiner's own functions and scored with the pooled EPE of ``projreg.evaluation.metrics`` (overall and the
three magnitude buckets), beside SIFT + RANSAC.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from projreg.evaluation.baselines import make_baseline
from projreg.evaluation.metrics import EPEAccumulator, sample_indices
from projreg.geometry.homography import fit_homography, fit_step, homography_flow
from projreg.geometry.images import normalize_contrast, texture_weight, to_gray
from projreg.geometry.warp import compose
from projreg.model.checkpoint import load_model, resolve_checkpoint
from projreg.refine.config import RefineConfig
from projreg.refine.refiner import GeometricRefiner
from projreg.training.validate import predict_flow
from projsynth.dataset.shards import ShardReader

ROWS = (
    "network alone",
    "homography fitted to it",
    "+ residual and refit (homography only)",
    "+ DIS residual as is",
    "+ B-spline residual instead (network hypothesis only)",
    "identity hypothesis only (no network)",
    "both hypotheses, plain images only",
    "both hypotheses, normalised images only",
    "both x both images, NCC selection (the default)",
    "sift-ransac (baseline)",
)


def stages(refiner: GeometricRefiner, variants: list[GeometricRefiner], sift, projected, captured, net):
    """The flow after each row of ``ROWS``, in order (``variants``: the two single-image-kind refiners)."""
    cfg = refiner.config
    h, w = net.shape[:2]
    step = fit_step(h, w, cfg.fit_points)
    gray0, gray1 = (normalize_contrast(to_gray(img), cfg.contrast_sigma) for img in (projected, captured))
    weight = texture_weight(gray0)
    everywhere = np.ones((h, w), bool)  # the stages without the guards: every pixel counts as evidence
    fit = fit_homography(net, step, cfg.ransac_px)
    H = np.eye(3) if fit is None else fit[0]
    base, residual, spline, _ = refiner.hypothesis(gray0, gray1, H, weight, step, everywhere, everywhere, net)
    identity = refiner.hypothesis(gray0, gray1, np.eye(3), weight, step, everywhere, everywhere, 0 * net)[2]
    return [
        net,
        homography_flow(H, h, w),
        base,
        compose(base, residual),
        spline,
        identity,
        *(v.refine(projected, captured, net)[0] for v in variants),
        refiner.refine(projected, captured, net)[0],
        sift.predict(projected, captured),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", default="reference")
    ap.add_argument("--every", type=int, default=None, help="every N-th sample")
    ap.add_argument("--limit", type=int, default=None, help="N samples spread evenly (as projreg bench)")
    args = ap.parse_args()
    torch.set_num_threads(2)
    device = torch.device("cpu")
    model = load_model(resolve_checkpoint(args.model), device)
    refiner = GeometricRefiner()
    variants = [GeometricRefiner(RefineConfig(contrast_sigma=0)), GeometricRefiner(RefineConfig(plain_pass=False))]
    sift = make_baseline("sift-ransac")
    reader = ShardReader(args.data)
    n = len(reader)
    indices = list(range(0, n, args.every)) if args.every else sample_indices(n, args.limit)
    accs = [EPEAccumulator() for _ in ROWS]
    try:
        for k in indices:
            s = reader.read(k)
            net = predict_flow(model, s["projected"], s["captured"], device)
            flows = stages(refiner, variants, sift, s["projected"], s["captured"], net)
            for acc, flow in zip(accs, flows, strict=True):
                acc.add(flow, s["flow"], s["valid"])
    finally:
        reader.close()
    print(f"{args.data}: {len(indices)} of {n} samples; EPE / s0-10 / s10-40 / s40+ (px)")
    for name, acc in zip(ROWS, accs, strict=True):
        r = acc.result()
        cells = ("-" if r[m] is None else f"{r[m]:.2f}" for m in ("epe", "s0-10", "s10-40", "s40+"))
        print(f"| {name} | {' / '.join(cells)} |")


if __name__ == "__main__":
    main()
