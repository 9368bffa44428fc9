"""The network's forward pass under each OpenMP wait policy, idle and beside a competing torch job.

    python bench/bench_threads.py [--reps 15] [--rounds 3]

Each measurement is a fresh process (the policy is read when torch's OpenMP runtime loads): the
reference network at 384 x 512, median of ``--reps`` passes after one warm-up, policies alternating
for ``--rounds``. Then the same beside a second process running the network in a loop with the
default policy. Prints milliseconds per pass; run on an otherwise idle machine and state its load
(docs/design.md, "Threads on a shared machine").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

PROBE = """
import statistics, sys, time
import numpy as np, torch
from projreg.inference.runtime import TorchNetwork
from projreg.model.checkpoint import load_model, reference_checkpoint
net = TorchNetwork(load_model(reference_checkpoint(), torch.device("cpu")), torch.device("cpu"))
rng = np.random.default_rng(0)
a, b = (rng.integers(0, 255, (1, 384, 512, 3), np.uint8) for _ in range(2))
net(a, b)
times = []
for _ in range(int(sys.argv[1])):
    t = time.perf_counter(); net(a, b); times.append(time.perf_counter() - t)
print(round(1000 * statistics.median(times)))
"""
POLICIES = {"default (spin)": None, "PASSIVE": "PASSIVE", "GOMP_SPINCOUNT=20000": "spin20000"}


def forward_ms(policy: str | None, reps: int) -> int:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    if policy == "PASSIVE":
        env["OMP_WAIT_POLICY"] = "PASSIVE"
    elif policy == "spin20000":
        env["GOMP_SPINCOUNT"] = "20000"
    run = subprocess.run([sys.executable, "-c", PROBE, str(reps)], env=env, capture_output=True, text=True, check=True)
    return int(run.stdout.strip())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at the start")
    for name, policy in POLICIES.items():
        print(f"idle    {name:22s}", [forward_ms(policy, args.reps) for _ in range(args.rounds)])
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    rival = subprocess.Popen([sys.executable, "-c", PROBE, "100000"], env=env, stdout=subprocess.DEVNULL)
    try:
        for name, policy in POLICIES.items():
            print(f"loaded  {name:22s}", [forward_ms(policy, max(3, args.reps // 3)) for _ in range(args.rounds)])
    finally:
        rival.kill()


if __name__ == "__main__":
    main()
