"""Where one generated sample's time goes: the stages of ``make_sample`` and of writing it.

Usage: python bench/profile_gen.py [--size 384x512] [--samples 64] [--families]

One process, one thread per library (as a ``gen`` worker), samples spread evenly over the transform
table (so over every family). Each stage is timed by wrapping the function that implements it;
``make_sample`` is the total of the rendering side, ``exr`` and ``hash`` run afterwards on the same
samples. Prints milliseconds per sample. ``--families`` also prints the forward + backward map time
per family (mean over the severities, condition studio, one scene each).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from projsynth.dataset import plan as dataset
from projsynth.dataset.generate import single_threaded
from projsynth.dataset.plan import make_sample, parse_size, resolve_plan, source_images
from projsynth.flow import formats as flowio
from projsynth.sim import render

STAGES = {
    dataset: ("make_scene",),
    render: ("forward", "alpha_field", "backward", "composite", "_stats"),  # composite samples the frame too
}


def _timed(fn: Callable, name: str, totals: dict) -> Callable:
    def wrapper(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[name] += time.perf_counter() - t

    return wrapper


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="384x512")
    ap.add_argument("--samples", type=int, default=64, help="samples to render (even)")
    ap.add_argument("--families", action="store_true", help="also time the two maps per family")
    args = ap.parse_args()
    spread = ",".join(str(i) for i in np.linspace(0, 159, args.samples // 2).astype(int))
    plan = resolve_plan(size=parse_size(args.size), seed=0, split="train", pairs=1, blend="paper", transforms=spread)
    images = source_images(plan, 0)
    make_sample(plan, 0, images)  # imports, numba cache, warm-up
    totals: dict[str, float] = defaultdict(float)
    for module, names in STAGES.items():
        for name in names:
            setattr(module, name, _timed(getattr(module, name), name, totals))
    n = plan.num_samples
    with single_threaded():
        t = time.perf_counter()
        samples = [make_sample(plan, k, images) for k in range(n)]
        totals["make_sample (total)"] = time.perf_counter() - t
        t = time.perf_counter()
        for s in samples:
            flowio.encode_flow_exr(s.flow, s.valid, s.id)
        totals["flow EXR encode"] = time.perf_counter() - t
        t = time.perf_counter()
        for s in samples:
            s.content_hash()
        totals["content hash"] = time.perf_counter() - t
    print(f"{n} samples at {plan.size[0]}x{plan.size[1]}, ms per sample:")
    for name, seconds in totals.items():
        print(f"  {name:20s} {1e3 * seconds / n:7.1f}")
    if args.families:
        _families(plan)


def _families(plan) -> None:  # noqa: ANN001
    from projsynth.sim.rig import make_scene
    from projsynth.sim.scene import backward, forward, pixel_grid

    grid = pixel_grid(*plan.size)
    print("forward + backward map per family, ms (mean over the severities, condition studio):")
    by_family: dict[str, list[float]] = defaultdict(list)
    with single_threaded():
        for cfg in plan.table.configs:
            if cfg.condition != "studio":
                continue
            scene, _ = make_scene(cfg.family, cfg.geometry, np.random.default_rng(cfg.id), plan.size)
            t = time.perf_counter()
            forward(scene, grid)
            backward(scene, grid)
            by_family[cfg.family].append(time.perf_counter() - t)
    for family, times in by_family.items():
        print(f"  {family:20s} {1e3 * float(np.mean(times)):7.1f}")


if __name__ == "__main__":
    main()
