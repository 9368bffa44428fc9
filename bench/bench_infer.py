"""Inference latency of the registration network and the fast path (docs/history/2026-11-log.md, "Inference latency").

Usage:
    python bench/bench_infer.py latency [--onnx build/onnx/reference.onnx] [--repeats 3] [--sizes 384x512,768x1024]
    python bench/bench_infer.py fast --data build/fresh-test [--onnx build/onnx/reference.onnx] [--limit 64]
        [--runtimes torch,onnxruntime]
    python bench/bench_infer.py graphs A.onnx B.onnx ... [--size 384x512] [--batch 1] [--rounds 7]

``latency``: ms per pair of the network alone on random images, for ``small`` (the shipped reference
weights) and ``base`` (random initialisation: the same operations, so the same time), PyTorch fp32 and
bf16 and, given ``--onnx`` (a graph of the reference, ``projreg export --onnx``), onnxruntime; batch 1
and 8 (8 at the smaller size only: the global softmaxes hold (H W / 64)^2 floats per pair, 0.6 GB at
768 x 1024). Median of ``--repeats`` calls after one warm-up call; ms per pair = call / batch.

``fast``: the network alone and each quality of the dial (``--quality``) on the samples of a dataset:
EPE (pooled over valid pixels, px) and median ms per pair, network and refinement timed apart.

``graphs``: ONNX graphs of one network (e.g. exported before and after a change) in onnxruntime,
interleaved A, B, A, B on one random pair so that a shared machine's load falls on all alike: median
wall-clock and process-CPU ms per pair, and each graph's flow against the first one's.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from projreg.evaluation.metrics import EPEAccumulator, sample_indices
from projreg.inference.runtime import OnnxNetwork, TorchNetwork, flows_resized
from projreg.model.checkpoint import load_model, reference_checkpoint
from projreg.model.net import build_model
from projreg.refine.config import QUALITIES
from projreg.refine.refiner import GeometricRefiner
from projsynth.dataset.plan import parse_size
from projsynth.dataset.shards import ShardReader

CPU = torch.device("cpu")


def _ms(call, repeats: int) -> tuple[float, float]:
    """Median wall-clock and process-CPU milliseconds of ``call`` over ``repeats`` calls after a warm-up.

    The CPU time is what the process itself used (all its threads): on a VM shared with other jobs it
    stays near the idle figure while the wall clock grows with the load.
    """
    call()  # warm-up: allocator, lazy initialisation, onnxruntime's first run
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        call()
        wall.append(1000 * (time.perf_counter() - t0))
        cpu.append(1000 * (time.process_time() - c0))
    return statistics.median(wall), statistics.median(cpu)


def _machine() -> str:
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    return (
        f"{platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__} ({torch.get_num_threads()} "
        f"threads), load average {load}"
    )


def latency(args: argparse.Namespace) -> None:
    small = load_model(reference_checkpoint(), CPU)
    base = build_model("base").eval()
    variants = [
        ("small", "torch fp32", lambda: TorchNetwork(small, CPU)),
        ("small", "torch bf16", lambda: TorchNetwork(load_model(reference_checkpoint(), CPU), CPU, torch.bfloat16)),
        ("base", "torch fp32", lambda: TorchNetwork(base, CPU)),
        ("base", "torch bf16", lambda: TorchNetwork(build_model("base").eval(), CPU, torch.bfloat16)),
    ]
    if args.onnx:
        variants.insert(2, ("small", "onnxruntime fp32", lambda: OnnxNetwork(args.onnx, CPU)))
    rng = np.random.default_rng(0)
    print(f"# {_machine()}")
    print("| model | runtime | size | batch | ms per pair (wall) | CPU ms per pair |\n|---|---|---|---|---|---|")
    for name, runtime, make in variants:
        net = make()
        for size in args.sizes.split(","):
            h, w = parse_size(size)
            for batch in (1, 8) if h * w <= 384 * 512 else (1,):
                img = rng.integers(0, 256, (batch, h, w, 3), dtype=np.uint8)
                wall, cpu = _ms(lambda net=net, img=img: net(img, img[:, ::-1, ::-1].copy()), args.repeats)
                print(
                    f"| {name} | {runtime} | {h} x {w} | {batch} | {wall / batch:.0f} | {cpu / batch:.0f} |", flush=True
                )
        del net
    print(f"# {_machine()}")


def fast(args: argparse.Namespace) -> None:
    reader = ShardReader(args.data)
    runtimes = args.runtimes.split(",")
    nets = {"torch": TorchNetwork(load_model(reference_checkpoint(), CPU), CPU)} if "torch" in runtimes else {}
    if args.onnx and "onnxruntime" in runtimes:
        nets["onnxruntime"] = OnnxNetwork(args.onnx, CPU)
    # (label, backend, network max side, refinement or None): the network alone, then each quality
    refiners = {name: GeometricRefiner(q.refine) for name, q in QUALITIES.items()}
    options = [("network alone", backend, 1024, None) for backend in ("torch", "onnxruntime")]
    for name, q in QUALITIES.items():
        options += [(f"network at {q.network_side} px alone", "onnxruntime", q.network_side, None)]
        options += [(f"--quality {name}", backend, q.network_side, name) for backend in ("torch", "onnxruntime")]
    options = [o for o in options if o[1] in nets]
    indices = sample_indices(len(reader), args.limit)
    samples = [reader.read(k) for k in indices]
    reader.close()
    acc = [EPEAccumulator() for _ in options]
    t_net, t_ref, t_cpu = ([[] for _ in options] for _ in range(3))
    for _, backend, side, _ in options:  # warm-up
        flows_resized(nets[backend], [(samples[0]["projected"], samples[0]["captured"])], side)
    print(f"# {args.data}: {len(samples)} samples, options interleaved per sample; {_machine()}")
    for s in samples:
        for i, (_, backend, side, ref) in enumerate(options):
            t0, c0 = time.perf_counter(), time.process_time()
            flow = flows_resized(nets[backend], [(s["projected"], s["captured"])], side)[0]
            t1 = time.perf_counter()
            if ref is not None:
                flow = refiners[ref].predict(s["projected"], s["captured"], flow).flow
            t2 = time.perf_counter()
            t_net[i].append(1000 * (t1 - t0))
            t_ref[i].append(1000 * (t2 - t1))
            t_cpu[i].append(1000 * (time.process_time() - c0))
            acc[i].add(flow, s["flow"], s["valid"])
    print("| option | runtime | EPE | s0-10 | s10-40 | s40+ | network ms | refinement ms | total ms | total CPU ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i, (label, backend, _, _) in enumerate(options):
        r = acc[i].result()
        epe = " | ".join(f"{r[k]:.2f}" for k in ("epe", "s0-10", "s10-40", "s40+"))
        ms = [statistics.median(t) for t in (t_net[i], t_ref[i], np.add(t_net[i], t_ref[i]), t_cpu[i])]
        print(f"| {label} | {backend} | {epe} | " + " | ".join(f"{m:.0f}" for m in ms) + " |")
    print(f"# {_machine()}")


def graphs(args: argparse.Namespace) -> None:
    import onnxruntime as ort

    def session(path: Path):
        options = ort.SessionOptions()
        options.intra_op_num_threads = torch.get_num_threads()
        options.log_severity_level = 3
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])

    sessions = [session(p) for p in args.onnx]
    h, w = parse_size(args.size)
    img = np.random.default_rng(0).integers(0, 256, (args.batch, 3, h, w)).astype(np.float32)
    feed = {"projected": img, "captured": img[:, :, ::-1, ::-1].copy()}
    flows = [s.run(None, feed)[0] for s in sessions]  # and the warm-up
    wall, cpu = [[] for _ in sessions], [[] for _ in sessions]
    print(f"# {h} x {w}, batch {args.batch}; {_machine()}")
    for _ in range(args.rounds):
        for i, s in enumerate(sessions):
            t0, c0 = time.perf_counter(), time.process_time()
            s.run(None, feed)
            wall[i].append(1000 * (time.perf_counter() - t0) / args.batch)
            cpu[i].append(1000 * (time.process_time() - c0) / args.batch)
    print("| graph | ms per pair (wall) | CPU ms per pair | flow vs the first: mean / max px |\n|---|---|---|---|")
    for path, flow, wl, cl in zip(args.onnx, flows, wall, cpu, strict=True):
        diff = np.abs(flow - flows[0])
        ms = f"{statistics.median(wl):.0f} | {statistics.median(cl):.0f}"
        print(f"| {path} | {ms} | {diff.mean():.1e} / {diff.max():.1e} |")
    print(f"# {_machine()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    lat = sub.add_parser("latency")
    lat.add_argument("--onnx", type=Path)
    lat.add_argument("--repeats", type=int, default=3)
    lat.add_argument("--sizes", default="384x512,768x1024")
    fst = sub.add_parser("fast")
    fst.add_argument("--data", type=Path, required=True)
    fst.add_argument("--onnx", type=Path)
    fst.add_argument("--limit", type=int)
    fst.add_argument(
        "--runtimes",
        default="torch,onnxruntime",
        help="one process per runtime: under load, "
        "onnxruntime's waiting threads slow torch's OpenMP workers down several times",
    )
    grp = sub.add_parser("graphs")
    grp.add_argument("onnx", type=Path, nargs="+")
    grp.add_argument("--size", default="384x512")
    grp.add_argument("--batch", type=int, default=1)
    grp.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    {"latency": latency, "fast": fast, "graphs": graphs}[args.what](args)


if __name__ == "__main__":
    main()
