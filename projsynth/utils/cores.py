"""Thread counts from the cores this process may run on, not the machine's.

``os.cpu_count()`` counts the machine; a container, a ``taskset`` or a batch scheduler's cgroup
usually grants fewer, and a pool sized to the machine oversubscribes them (on a shared 2-core VM the
network ran faster with one thread than with its default). ``os.sched_getaffinity(0)`` is the set
this process is allowed.
"""

from __future__ import annotations

import os

import cv2


def available_cores() -> int:
    """The number of cores this process may run on (its CPU affinity; the machine's where unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # macOS and Windows have no sched_getaffinity
        return os.cpu_count() or 1


def use_available_cores() -> int:
    """Size OpenCV's and numba's thread pools to :func:`available_cores`; returns that count.

    An explicit ``NUMBA_NUM_THREADS`` is left as the user set it.
    """
    n = available_cores()
    cv2.setNumThreads(n)
    if "NUMBA_NUM_THREADS" not in os.environ:
        import numba

        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    return n
