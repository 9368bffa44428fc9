"""The network and the whole pipeline under each way of running torch's threads, idle and beside a
competing torch job.

    python bench/bench_threads.py [--side 256] [--reps 15] [--rounds 2] [--data DIR --pairs 12]

Each measurement is a fresh process (the OpenMP wait policy is read when torch's OpenMP runtime
loads). Cases: torch with OpenMP's default (spinning) workers, torch with ``OMP_WAIT_POLICY=PASSIVE``
(what the command lines set), and onnxruntime running the shipped reference graph with its threads
sleeping when out of work (``--backend auto``'s choice on the CPU). Without ``--data``: the reference
network's forward pass at ``--side`` (random images, 3:4), median of ``--reps`` passes after one warm-up.
With ``--data`` (a ``projsynth gen`` set): ``Registrar.register`` (network and refinement) on its first
``--pairs`` pairs for ``--quality fast`` and ``balanced``, median ms per pair and, in brackets, the
network's share. Then the same beside a second process running the network at 384 x 512 in a loop with
the default policy. Run on an otherwise idle machine and state its load (docs/design.md, "Threads on a
shared machine").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

NETWORK = """
import statistics, sys, time
import numpy as np
from projreg.inference.runtime import open_network
net = open_network(None, backend=sys.argv[1])
side, reps = int(sys.argv[2]), int(sys.argv[3])
rng = np.random.default_rng(0)
a, b = (rng.integers(0, 255, (1, side * 3 // 4, side, 3), np.uint8) for _ in range(2))
net(a, b)
times = []
for _ in range(reps):
    t = time.perf_counter(); net(a, b); times.append(time.perf_counter() - t)
print(round(1000 * statistics.median(times)))
"""
PIPELINE = """
import statistics, sys, time
from pathlib import Path
from projreg.api import Registrar
from projsynth.dataset.shards import ShardReader
reader = ShardReader(Path(sys.argv[2]))
pairs = [(s["projected"], s["captured"]) for s in (reader.read(k) for k in range(int(sys.argv[3]) + 1))]
reg = Registrar(quality=sys.argv[4], backend=sys.argv[1])
reg.register(*pairs[-1])
times, network = [], []
for a, b in pairs[:-1]:
    t = time.perf_counter(); r = reg.register(a, b); times.append(time.perf_counter() - t)
    network.append(r.timings["network"])
print(f"{1000 * statistics.median(times):.0f} ({statistics.median(network):.0f})")
"""
RIVAL = """
import numpy as np
from projreg.inference.runtime import open_network
net = open_network(None, backend="torch")
rng = np.random.default_rng(0)
a, b = (rng.integers(0, 255, (1, 384, 512, 3), np.uint8) for _ in range(2))
while True:
    net(a, b)
"""
CASES = {
    "torch, default (spin)": ("torch", {}),
    "torch, PASSIVE": ("torch", {"OMP_WAIT_POLICY": "PASSIVE"}),
    "onnxruntime, no spin (auto)": ("auto", {"OMP_WAIT_POLICY": "PASSIVE"}),
}


def _env(extra: dict[str, str]) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    return {**env, **extra}


def measure(case: str, args: argparse.Namespace, quality: str | None, loaded: bool) -> str:
    backend, extra = CASES[case]
    if quality is None:
        code, argv = NETWORK, [backend, str(args.side), str(max(3, args.reps // 3) if loaded else args.reps)]
    else:
        code, argv = (
            PIPELINE,
            [backend, str(args.data), str(max(3, args.pairs // 2) if loaded else args.pairs), quality],
        )
    run = subprocess.run(
        [sys.executable, "-c", code, *argv], env=_env(extra), capture_output=True, text=True, check=True
    )
    return run.stdout.strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=256, help="the network's input width (height 3/4 of it)")
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--data", help="a projsynth set: time the pipeline on its first pairs instead")
    ap.add_argument("--pairs", type=int, default=12)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at the start")
    qualities = ["fast", "balanced"] if args.data else [None]
    for phase in ("idle", "loaded"):
        rival = None
        if phase == "loaded":
            rival = subprocess.Popen([sys.executable, "-c", RIVAL], env=_env({}), stdout=subprocess.DEVNULL)
        try:
            for quality in qualities:
                for case in CASES:
                    runs = [measure(case, args, quality, phase == "loaded") for _ in range(args.rounds)]
                    print(f"{phase:7s} {quality or f'network {args.side} px':12s} {case:28s}", " / ".join(runs))
        finally:
            if rival is not None:
                rival.kill()


if __name__ == "__main__":
    main()
