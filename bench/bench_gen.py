"""Generation throughput vs. its I/O floor, peak memory per worker, and random-read latency.

Usage: python bench/bench_gen.py [--size 384x512] [--samples 64]

With 2 workers each run also pays two process start-ups (imports and the numba cache, about 1 s), so
small runs understate steady-state throughput: use ``--samples 512`` for that.

All figures come from one run so their ratios are comparable:
* gen 1 / 2 workers: ``projsynth.dataset.generate.generate`` end to end (samples/s).
* floor: per sample, decode two PNG sources + ``cv2.remap`` + EXR encode + HDF5 write, i.e. what any
  generator writing this format must do; the ratio gen/floor is the cost of the simulation itself.
  The flows encoded (and remapped by) are real generated ones, cycled: EXR's ZIP takes twice as long
  on them as on a smooth synthetic flow (21 vs 10 ms), which the floor measured before 2026-11-24 used
  and which is still printed for comparison. Measured on one core and on two (two processes, each
  half the samples, started together).
* peak RSS of a worker rendering and writing one shard (``ru_maxrss`` of a child process).
* random read: one sample (both images + flow EXR decode) from a finished dataset, wall and CPU time.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import h5py
import numpy as np

from projsynth.dataset.generate import _write_one, generate
from projsynth.dataset.plan import make_sample, parse_size, resolve_plan, source_images
from projsynth.dataset.shards import ShardReader
from projsynth.flow.formats import encode_flow_exr


def _gen_rate(plan, shard_size: int, workers: int) -> float:
    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        generate(plan, Path(d) / "ds", shard_size=shard_size, workers=workers)
        return plan.num_samples / (time.perf_counter() - t)


def _floor_worker(plan, n: int, barrier, results) -> None:  # noqa: ANN001
    results.put(_floor_rate(plan, n, barrier=barrier))


def _floor_rate_2cores(plan, n: int) -> float:
    """The floor in two processes at once (both start their timed loop together): summed samples/s."""
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_floor_worker, args=(plan, n // 2, barrier, results)) for _ in range(2)]
    for p in procs:
        p.start()
    rates = [results.get(timeout=1800) for _ in procs]  # a crashed child raises queue.Empty, not a hang
    for p in procs:
        p.join()
    return sum(rates)


def _floor_content(plan, synthetic: bool) -> list[tuple[np.ndarray, np.ndarray]]:  # noqa: ANN001
    """(flow, valid) pairs the floor encodes and remaps by: 16 generated samples spread over the plan's
    transforms, or (``synthetic``) one smooth affine flow, valid everywhere."""
    h, w = plan.size
    if synthetic:
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        return [(np.dstack([xs * -0.03 + 3.3, ys * 0.02 - 2.1]).astype(np.float32), np.ones((h, w), bool))]
    picks = np.linspace(0, plan.num_samples - 1, min(16, plan.num_samples)).astype(int)
    return [(s.flow, s.valid) for s in (make_sample(plan, int(k)) for k in picks)]


def _floor_rate(plan, n: int, *, synthetic: bool = False, barrier=None) -> float:  # noqa: ANN001
    h, w = plan.size
    nat, gen, _ = source_images(plan, 0)
    content = _floor_content(plan, synthetic)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    maps = [(xs + flow[..., 0], ys + flow[..., 1]) for flow, _ in content]
    with tempfile.TemporaryDirectory() as d:
        pngs = [cv2.imencode(".png", im)[1].tobytes() for im in (nat, gen)]
        if barrier is not None:
            barrier.wait()
        t = time.perf_counter()
        with h5py.File(Path(d) / "floor.h5", "w") as f:
            opts = {"compression": "lzf", "chunks": (1, h, w, 3)}
            a = f.create_dataset("a", (n, h, w, 3), np.uint8, **opts)
            b = f.create_dataset("b", (n, h, w, 3), np.uint8, **opts)
            e = f.create_dataset("e", (n,), h5py.vlen_dtype(np.uint8))
            for i in range(n):
                (flow, valid), (mx, my) = content[i % len(content)], maps[i % len(content)]
                src = [cv2.imdecode(np.frombuffer(p, np.uint8), cv2.IMREAD_COLOR) for p in pngs]
                a[i] = src[0]
                b[i] = cv2.remap(src[1], mx, my, cv2.INTER_LINEAR)
                e[i] = np.frombuffer(encode_flow_exr(flow, valid, "floor"), np.uint8)
        return n / (time.perf_counter() - t)


def _child_peak(job) -> int:
    _write_one(job)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux


def _read_ms(plan, shard_size: int) -> tuple[float, float]:
    """Median wall and CPU milliseconds of reading one random sample (50 reads)."""
    with tempfile.TemporaryDirectory() as d:
        generate(plan, Path(d) / "ds", shard_size=shard_size)
        reader = ShardReader(Path(d) / "ds")
        rng = np.random.default_rng(0)
        wall, cpu = [], []
        for k in rng.integers(0, len(reader), 50):
            t, c = time.perf_counter(), time.process_time()
            reader.read(int(k))
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        reader.close()
        return 1e3 * statistics.median(wall), 1e3 * statistics.median(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="384x512")
    ap.add_argument("--samples", type=int, default=64, help="samples per measurement (even)")
    args = ap.parse_args()
    size = parse_size(args.size)
    # up to 64 transforms spread evenly over every family; more samples = more pairs
    per_role = min(args.samples // 2, 64)
    spread = ",".join(str(i) for i in np.linspace(0, 159, per_role).astype(int))
    plan = resolve_plan(
        size=size, seed=0, split="train", pairs=max(1, args.samples // (2 * per_role)), blend="paper", transforms=spread
    )
    one_pair = resolve_plan(size=size, seed=0, split="train", pairs=1, blend="paper", transforms=spread)
    half = one_pair.num_samples // 2
    make_sample(plan, 0)  # warm caches and imports
    print(f"machine: {platform.machine()} {mp.cpu_count()} cores, python {platform.python_version()}")
    shard = 16  # several shards per worker, so 2 workers stay busy to the end
    print(f"size {size[0]}x{size[1]}, {plan.num_samples} samples per gen run, shards of {shard}")
    r1 = _gen_rate(plan, shard, 1)
    r2 = _gen_rate(plan, shard, 2)
    fl = _floor_rate(plan, plan.num_samples)
    fl2 = _floor_rate_2cores(plan, plan.num_samples)
    fls = _floor_rate(plan, plan.num_samples, synthetic=True)
    print(f"gen  1 worker : {r1:6.1f} samples/s")
    print(f"gen  2 workers: {r2:6.1f} samples/s  ({r2 / r1:.2f}x of 1 worker)")
    print(f"floor 1 core  : {fl:6.1f} samples/s  (gen 1 worker is {fl / r1:.1f}x slower than the floor)")
    print(f"floor 2 cores : {fl2:6.1f} samples/s  (gen 2 workers are {fl2 / r2:.1f}x slower than the floor)")
    print(f"floor 1 core, synthetic affine flow (before 2026-11-24): {fls:6.1f} samples/s  ({fls / r1:.1f}x)")
    with mp.get_context("spawn").Pool(1) as pool:
        peak = pool.apply(_child_peak, ((one_pair, Path(tempfile.mkdtemp()), half, 0, one_pair.config_hash()),))
    print(f"peak RSS of one worker writing a {half}-sample shard: {peak / 1024:.0f} MiB")
    wall, cpu = _read_ms(one_pair, half)
    print(f"random read (images + EXR decode): {wall:.2f} ms median of 50 ({cpu:.2f} ms CPU, both threads)")


if __name__ == "__main__":
    main()
