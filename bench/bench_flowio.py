"""Time flow EXR encode/decode at 384 x 512 and report the encoded size.

Usage: python bench/bench_flowio.py [--reps 30]

The flow is smooth (a projective warp plus a bump, as projsynth scenes produce) with an invalid
region; a random-noise flow is timed too, as the incompressible worst case. The peer is Python's zlib
(level 4) on the raw float32 channel bytes, measured in the same run.
"""

import argparse
import platform
import statistics
import time
import zlib

import numpy as np
import OpenEXR

from projsynth.flow.formats import decode_flow_exr, encode_flow_exr

H, W = 384, 512


def smooth_flow() -> tuple[np.ndarray, np.ndarray]:
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    d = 1 + 2e-4 * x + 1e-4 * y  # projective denominator
    cx, cy = (1.05 * x + 0.03 * y + 12) / d, (0.02 * x + 0.97 * y - 7) / d
    bump = 6 * np.exp(-((x - 300) ** 2 + (y - 150) ** 2) / (2 * 60**2))
    flow = np.stack([cx - x + bump, cy - y - bump], axis=-1).astype(np.float32)  # [H, W, 2]
    valid = ((x - 100) ** 2 + (y - 250) ** 2 > 50**2) & (x < W - 20)
    return flow, valid


def median_ms(fn, reps: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=30)
    args = parser.parse_args()
    print(
        f"# {platform.processor() or platform.machine()}, python {platform.python_version()}, "
        f"numpy {np.__version__}, OpenEXR {OpenEXR.__version__}, {H}x{W}, median of {args.reps}"
    )
    rng = np.random.default_rng(0)
    noise = (rng.uniform(-60, 60, (H, W, 2)).astype(np.float32), rng.random((H, W)) < 0.9)
    for name, (flow, valid) in [("smooth", smooth_flow()), ("noise", noise)]:
        raw = b"".join(np.ascontiguousarray(c).tobytes() for c in (flow[..., 0], flow[..., 1], valid * 1.0))
        peer_ms = median_ms(lambda raw=raw: zlib.compress(raw, 4), args.reps)
        print(f"{name}: raw {len(raw)} B, zlib-4 peer {peer_ms:.2f} ms -> {len(zlib.compress(raw, 4))} B")
        for compression in ("zip", "pxr24"):
            data = encode_flow_exr(flow, valid, "bench", compression)
            enc = median_ms(
                lambda f=flow, v=valid, c=compression: encode_flow_exr(f, v, "bench", c), args.reps
            )
            dec = median_ms(lambda d=data: decode_flow_exr(d), args.reps)
            print(
                f"  {compression:5s} encode {enc:7.2f} ms ({enc / peer_ms:.2f}x peer)  "
                f"decode {dec:6.2f} ms  size {len(data):8d} B ({len(data) / len(raw):.1%} of raw)"
            )


if __name__ == "__main__":
    main()
