"""How much of a frame the refinement's checks pass by chance: photos of another picture.

Usage: python bench/chance_claims.py [--size 512x384] [--quality balanced] [--windows 6]

Each of scikit-image's pictures below is projected bent (the tests' ``bent_pair``) and "photographed" as
each other one (132 ordered pairs); the network's flow is the tests' ``network_like`` of the projected
picture's true map. Prints, per pair whose checks pass on more than 0.5 % of the frame, that share and
whether the pair registers, then the distribution and the count of registered pairs. ``chelsea`` and
``cat`` are one photograph: those two pairs register rightly. ``--windows`` overrides
``confidence.registered_windows`` (0: the share rule alone). Figures: docs/history/2026-12-02-pool.md.
"""

import argparse
import itertools
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' renderer

from projreg.prediction import CONFIDENT  # noqa: E402
from projreg.refine.config import quality  # noqa: E402
from projreg.refine.refiner import GeometricRefiner  # noqa: E402
from tests.projreg.refine.rendered import bent_pair, network_like  # noqa: E402

PICTURES = ("astronaut", "chelsea", "coffee", "camera", "rocket", "coins", "moon", "page", "text")
PICTURES += ("immunohistochemistry", "cat", "brick")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="512x384", help="W x H of the pairs")
    ap.add_argument("--quality", default="balanced")
    ap.add_argument("--windows", type=float, default=None, help="confidence.registered_windows")
    args = ap.parse_args()
    import skimage.data

    w, h = (int(v) for v in args.size.split("x"))
    pictures = {}
    for name in PICTURES:
        image = getattr(skimage.data, name)()
        image = np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image[..., :3]
        pictures[name] = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    config = quality(args.quality).refine
    if args.windows is not None:
        config = config.with_sections(confidence={"registered_windows": args.windows})
    refiner = GeometricRefiner(config)
    bend = {"amp": 3.0 * w / 256, "period": 150.0 * w / 256}  # the tests' bend, scaled with the frame
    shares, registered = [], 0
    for a, b in itertools.permutations(PICTURES, 2):
        projected, _, truth, valid = bent_pair(pictures[a], **bend)
        _, captured, _, _ = bent_pair(pictures[b], seed=5, **bend)
        flow = network_like(truth, np.ones(valid.shape, bool), np.random.default_rng(12))
        pred, info = refiner.predict_info(projected, captured, flow)
        share = float((info.confidence >= CONFIDENT).mean())
        shares.append(share)
        registered += pred.registered
        if share > 0.005:
            print(f"{a:>20s} <- {b:<20s} checks pass on {100 * share:5.2f} %  registered {pred.registered}")
    s = 100 * np.array(shares)
    print(
        f"{args.size} {args.quality}: {len(s)} pairs; the checks pass on: median {np.median(s):.2f} %, "
        f"p90 {np.percentile(s, 90):.2f} %, max {s.max():.2f} %; registered: {registered}"
    )


if __name__ == "__main__":
    main()
