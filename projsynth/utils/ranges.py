"""Parameter ranges and the uniform draw inside them that every random scene parameter comes from."""

from __future__ import annotations

import numpy as np

Ranges = dict[str, tuple[float, float]]


def draw(rng: np.random.Generator, ranges: Ranges) -> dict[str, float]:
    """Draw every parameter uniformly inside its range, in sorted key order (stable across versions)."""
    return {k: float(rng.uniform(*ranges[k])) for k in sorted(ranges)}
