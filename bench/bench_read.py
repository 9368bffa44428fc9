"""Random-read latency of two datasets of the same samples, interleaved in one process.

Usage: python bench/bench_read.py A B [--reads 400]

Reads sample ``k`` from A, then the same ``k`` from B, for random ``k`` (``ShardReader.read``: both
images, the flow EXR decode and the parameters, as ``bench_gen.py``'s random read), so both see the
same machine load. Made for format 1 vs format 2 (checksums) on datasets of one ``gen`` command:
write A with the format 1 code (``git archive 242a210 | tar -x -C /tmp/f1``, then its
``projsynth gen``) and B with this one.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from projsynth.dataset.shards import ShardReader


def _timed(reader: ShardReader, k: int) -> tuple[float, float]:
    t, c = time.perf_counter(), time.process_time()
    reader.read(k)
    return 1e3 * (time.perf_counter() - t), 1e3 * (time.process_time() - c)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=Path)
    ap.add_argument("b", type=Path)
    ap.add_argument("--reads", type=int, default=400)
    args = ap.parse_args()
    readers = [ShardReader(args.a), ShardReader(args.b)]
    if len(readers[0]) != len(readers[1]):
        raise SystemExit("the two datasets differ in size")
    times: list[list[tuple[float, float]]] = [[], []]
    for k in np.random.default_rng(0).integers(0, len(readers[0]), args.reads):
        for r, out in zip(readers, times, strict=True):
            out.append(_timed(r, int(k)))
    for path, r, out in zip((args.a, args.b), readers, times, strict=True):
        wall, cpu = (statistics.median(v) for v in zip(*out, strict=True))
        print(
            f"{path} (format {r.manifest['format_version']}): {wall:.2f} ms wall, {cpu:.2f} ms CPU "
            f"(median of {args.reads})"
        )
        r.close()


if __name__ == "__main__":
    main()
