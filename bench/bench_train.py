"""Training and inference speed of the registration net on this machine, with the loader beside it.

Usage: python bench/bench_train.py [--model small] [--batch 8] [--size 384x512] [--steps 3]
                                   [--device cpu|cuda] [--amp] [--compile] [--no-activation-checkpointing]

Prints, from one run: DataLoader samples/s (full frames, augmentation on), training samples/s
(forward + backward + AdamW step, uint8 images normalised on the device as in `projreg train`),
inference ms per pair (batch 1, eval), and the peak memory: RSS of the process, and on CUDA the peak
allocated GPU memory of the training steps.
"""

from __future__ import annotations

import argparse
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from projreg.model.net import build_model, count_parameters
from projreg.training.data import Augment, ShardDataset, StreamSampler
from projreg.training.loss import sequence_loss
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import parse_size, resolve_plan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="small")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--size", default="384x512")
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-activation-checkpointing", action="store_true", help="as `projreg train`'s option")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    ap.add_argument("--amp", action="store_true", help="bf16 autocast (CUDA), as `projreg train --amp`")
    ap.add_argument("--compile", action="store_true", help="torch.compile the model (the first step compiles)")
    args = ap.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda":
        torch.cuda.set_device(device)
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    h, w = parse_size(args.size)
    torch.manual_seed(0)
    with tempfile.TemporaryDirectory() as d:
        every_tenth = ",".join(str(i) for i in range(0, 160, 10))
        plan = resolve_plan(size=(h, w), seed=0, split="train", pairs=1, transforms=every_tenth, blend="paper")
        generate(plan, Path(d) / "ds", shard_size=16, workers=2)
        ds = ShardDataset([Path(d) / "ds"], Augment(crop=(h, w), scale=(1.0, 1.0)))
        loader = DataLoader(ds, batch_size=args.batch, sampler=StreamSampler(len(ds), 0), num_workers=args.workers)
        it = iter(loader)
        next(it)
        t = time.perf_counter()
        n = 4
        for _ in range(n):
            next(it)
        load_rate = n * args.batch / (time.perf_counter() - t)

        model = build_model(args.model).to(device)
        model.transformer.checkpointing = not args.no_activation_checkpointing
        net = torch.compile(model) if args.compile else model
        opt = torch.optim.AdamW(model.parameters(), lr=4e-4)
        batch = {k: v.to(device) for k, v in next(it).items()}
        autocast = torch.autocast("cuda", dtype=torch.bfloat16, enabled=args.amp and device.type == "cuda")
        times = []
        for _ in range(args.steps + 2):  # the first two warm up (cuDNN autotuning, compilation)
            t = time.perf_counter()
            with autocast:
                preds = net(batch["img0"], batch["img1"])
            loss, _ = sequence_loss([p.float() for p in preds], batch["flow"], batch["valid"])
            opt.zero_grad()
            loss.backward()
            opt.step()
            _sync(device)
            times.append(time.perf_counter() - t)
        train_rate = args.batch / statistics.median(times[2:])
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB
        gpu_peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else None

        model.eval()
        x0, x1 = batch["img0"][:1], batch["img1"][:1]
        inf = []
        with torch.no_grad(), autocast:
            for _ in range(6):
                t = time.perf_counter()
                net(x0, x1)
                _sync(device)
                inf.append(time.perf_counter() - t)
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{torch.get_num_threads()} threads"
    print(f"machine: {platform.machine()}, torch {torch.__version__}, {where}")
    print(f"options: amp {args.amp}, compile {args.compile}, checkpointing {not args.no_activation_checkpointing}")
    print(f"model {args.model}: {count_parameters(model) / 1e6:.2f} M parameters; batch {args.batch} at {h}x{w}")
    print(f"loader ({args.workers} workers): {load_rate:6.1f} samples/s")
    print(f"training step:     {train_rate:6.2f} samples/s ({statistics.median(times[2:]):.3f} s/step)")
    print(f"inference:         {1e3 * statistics.median(inf[1:]):6.0f} ms per pair (batch 1)")
    print(f"peak RSS:          {peak:6.0f} MiB")
    if gpu_peak is not None:
        print(f"peak GPU memory:   {gpu_peak:6.0f} MiB (training steps)")
    print(
        f"result: model={args.model} checkpointing={not args.no_activation_checkpointing} batch={args.batch} "
        f"samples_per_s={train_rate:.3f} gpu_peak_mib={gpu_peak or 0:.0f}"
    )


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


if __name__ == "__main__":
    main()
