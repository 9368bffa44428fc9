"""The refinement's threads: one pool per process, and each thread's own DIS instance.

OpenCV and numpy release the GIL, so a stage's candidates refine side by side on ``search.workers``
threads; with one worker everything runs on the caller's thread, in the same order, to the same answer.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import cv2
import numpy as np

POOL_NAME = "refine"  # the prefix of the pool's thread names


class Workers:
    """``count`` threads for one refiner (none below two), started on first use in each process (a forked
    child starts its own), and a DIS instance per thread (DIS keeps state between calls)."""

    def __init__(self, count: int) -> None:
        self.count = count
        self._pools: dict[int, ThreadPoolExecutor] = {}
        self._local = threading.local()

    def submit(self, fn: Callable, *args) -> Future:
        """``fn(*args)`` on the pool; done at once on this thread without a pool, or from one of its own
        threads (which would otherwise wait on a queue they feed)."""
        pool = self._pool()
        if pool is not None and not threading.current_thread().name.startswith(POOL_NAME):
            return pool.submit(fn, *args)
        done: Future = Future()
        done.set_result(fn(*args))
        return done

    def dis(self) -> cv2.DISOpticalFlow:
        """This thread's DIS (OpenCV's medium preset)."""
        dis = getattr(self._local, "dis", None)
        if dis is None:
            dis = self._local.dis = cv2.DISOpticalFlow_create(cv2.DISOpticalFlow_PRESET_MEDIUM)
        return dis

    def dis_flows(self, pairs: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
        """DIS's flow of each ``(image0, image1)`` pair, side by side: the last on this thread, which would
        otherwise only wait (a pool thread may be busy with work started ahead, e.g. a re-alignment)."""
        jobs = [self.submit(lambda a, b: self.dis().calc(a, b, None), *pair) for pair in pairs[:-1]]
        last = [self.dis().calc(*pairs[-1], None)] if pairs else []
        return [job.result() for job in jobs] + last

    def _pool(self) -> ThreadPoolExecutor | None:
        if self.count < 2:
            return None
        pid = os.getpid()
        if pid not in self._pools:
            self._pools = {pid: ThreadPoolExecutor(self.count, thread_name_prefix=POOL_NAME)}
        return self._pools[pid]
