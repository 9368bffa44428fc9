"""``projsynth gen``: render a plan into shards, in parallel, resumably.

Work is split by shard: each worker process renders a whole shard and writes it atomically, so
nothing crosses process boundaries but shard indices, and a killed run leaves only ``*.tmp`` files,
which the next run removes. Finished shards (same config hash) are skipped. A run holds a lock on
its shards (``.gen.lock``), so two runs never write one shard.
"""

from __future__ import annotations

import dataclasses
import fcntl
import multiprocessing as mp
import os
import queue
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
from threadpoolctl import threadpool_limits

from ..errors import ProjsynthError
from ..utils.jit import KERNELS, uncompiled_kernels
from ..utils.outputs import refuse_foreign_files
from ..versions import FORMAT_VERSION, __version__
from .plan import Plan, make_sample, sample_key, source_images
from .shards import (
    MANIFEST,
    PLAN_FILE,
    assemble_manifest,
    is_dataset_file,
    library_versions,
    read_json,
    shard_is_complete,
    shard_name,
    write_json_atomic,
    write_shard,
)

LOCK_FILE = ".gen.lock"
SHARD_SIZE = 64  # the default: samples per shard (rounded down to whole sequences)


@dataclass(frozen=True)
class GenResult:
    written: list[int]
    skipped: list[int]
    num_shards: int
    manifest: dict | None  # None while some shards of the plan are still missing


def default_shard_size(frames: int) -> int:
    """``SHARD_SIZE`` samples, rounded down to whole sequences of ``frames`` (at least one)."""
    return max(1, SHARD_SIZE // frames) * frames


def parse_shard_range(spec: str | None, num_shards: int) -> range:
    """``"40-79"``, ``"3"``, ``"K/N"`` (array task K of N, from 0: its contiguous share of the plan's
    shards, empty when there are more tasks than shards) or None (all) -> shard indices, checked
    against the plan.

    Example:
        >>> [list(parse_shard_range(f"{k}/3", 7)) for k in range(3)]
        [[0, 1], [2, 3], [4, 5, 6]]
    """
    if spec is None:
        return range(num_shards)
    if "/" in spec:
        return _task_share(spec, num_shards)
    try:
        lo, _, hi = spec.partition("-")
        a, b = int(lo), int(hi) if hi else int(lo)
    except ValueError:
        raise ProjsynthError(f"--shards: cannot parse {spec!r}; use e.g. 40-79 or 3/16") from None
    if not 0 <= a <= b < num_shards:
        raise ProjsynthError(f"--shards: {spec} is outside 0-{num_shards - 1} (this plan has {num_shards} shards)")
    return range(a, b + 1)


def _task_share(spec: str, num_shards: int) -> range:
    """Task ``K`` of ``N``'s shards: shards ``[K * S // N, (K + 1) * S // N)`` of the plan's ``S``, so the
    shares differ by at most one shard and together cover the plan once."""
    try:
        k, n = (int(part) for part in spec.split("/"))
    except ValueError:
        raise ProjsynthError(f"--shards: cannot parse {spec!r}; use TASK/TASKS, e.g. 3/16") from None
    if n < 1:
        raise ProjsynthError(f"--shards: {spec}: the number of tasks must be >= 1")
    if not 0 <= k < n:
        raise ProjsynthError(f"--shards: {spec}: the task index must be in 0..{n - 1} (0-based, as array tasks)")
    return range(k * num_shards // n, (k + 1) * num_shards // n)


def generate(
    plan: Plan,
    out: Path,
    *,
    shard_size: int,
    shards: str | None = None,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
    progress_total: Callable[[int], None] | None = None,
    status: Callable[[str], None] | None = None,
) -> GenResult:
    """Write the shards of ``plan`` under ``out`` (a subset with ``shards``) and, when all exist,
    the manifest. ``progress_total(n)`` is called once with the samples of the selected shards,
    ``progress(n)`` with the samples already done, then with 1 per sample rendered; ``status(line)``
    with a line about a first run's kernel compilation (before and after it).

    Raises:
        ProjsynthError: bad options, an ``out`` holding another dataset or files ``gen`` does not
            write, another ``gen`` writing some of the same shards (:func:`claim_shards`), or a shard
            that cannot be written.
    """
    if shard_size < 1:
        raise ProjsynthError(f"--shard-size: must be >= 1, got {shard_size}")
    if shard_size % plan.frames:
        raise ProjsynthError(
            f"--shard-size: {shard_size} is not a multiple of --frames {plan.frames} (a shard holds "
            f"whole sequences); use e.g. {default_shard_size(plan.frames)}"
        )
    if workers < 1:
        raise ProjsynthError(f"--workers: must be >= 1, got {workers}")
    num_shards = -(-plan.num_samples // shard_size)
    todo_range = parse_shard_range(shards, num_shards)
    info = {
        **plan.describe(),
        "config_hash": plan.config_hash(),
        "shard_size": shard_size,
        "num_shards": num_shards,
        "skipped_sources": list(plan.skipped),
    }
    _prepare_dir(out, info)
    with claim_shards(out, todo_range):
        todo, done = [], []
        for j in todo_range:
            (out / (shard_name(j) + ".tmp")).unlink(missing_ok=True)  # left by an interrupted run
            (done if shard_is_complete(out / shard_name(j), info["config_hash"]) else todo).append(j)
        if todo:
            compile_kernels(plan, status)  # before the bar: it would sit at 0 % meanwhile
        if progress_total:
            progress_total(sum(_shard_count(plan, shard_size, j) for j in todo_range))
        if progress:
            progress(sum(_shard_count(plan, shard_size, j) for j in done))
        jobs = [(plan, out, shard_size, j, info["config_hash"]) for j in todo]
        if workers == 1 or len(jobs) <= 1:
            with single_threaded():
                for job in jobs:
                    _write_one(job, progress)
        else:
            _write_in_pool(jobs, min(workers, len(jobs)), progress)
    manifest = None
    if all(shard_is_complete(out / shard_name(j), info["config_hash"]) for j in range(num_shards)):
        manifest = assemble_manifest(out, info, num_shards, shard_size)
    return GenResult(todo, done, num_shards, manifest)


def merge(out: Path) -> dict:
    """Assemble ``manifest.json`` once every shard of the plan in ``out`` exists (job arrays)."""
    info = read_json(out / PLAN_FILE, "plan")
    if not {"num_shards", "config_hash", "shard_size"} <= info.keys():
        raise ProjsynthError(f"{out / PLAN_FILE}: not a projsynth plan; regenerate the dataset")
    missing = [j for j in range(info["num_shards"]) if not shard_is_complete(out / shard_name(j), info["config_hash"])]
    if missing:
        raise ProjsynthError(
            f"{out}: {len(missing)} of {info['num_shards']} shards missing or incomplete "
            f"(first: {shard_name(missing[0])}); generate them with --shards"
        )
    return assemble_manifest(out, info, info["num_shards"], info["shard_size"])


def _prepare_dir(out: Path, info: dict) -> None:
    refuse_foreign_files(out, is_dataset_file, "projsynth gen")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create directory ({e.strerror}); choose a writable path") from e
    plan_path = out / PLAN_FILE
    if plan_path.exists():
        try:
            old = read_json(plan_path, "plan")
        except ProjsynthError:
            old = {}
        if old.get("generator", info["generator"]) != info["generator"]:
            raise ProjsynthError(
                f"--out {out}: holds a dataset made by {old['generator']}, whose samples differ from "
                f"{info['generator']}'s; use a new --out, or delete it to regenerate"
            )
        if old.get("format_version", FORMAT_VERSION) != FORMAT_VERSION:
            raise ProjsynthError(
                f"--out {out}: holds a format {old['format_version']} dataset, this projsynth "
                f"writes format {FORMAT_VERSION}; use a new --out (the old one stays readable)"
            )
        if old.get("config_hash") != info["config_hash"] or old.get("shard_size") != info["shard_size"]:
            raise ProjsynthError(
                f"--out {out}: holds a dataset made with other options (see {plan_path}); "
                "use a new --out, or the same options to resume"
            )
        return
    if (out / MANIFEST).exists() or any(out.glob("shard-*.h5")):
        raise ProjsynthError(f"--out {out}: holds shards without {PLAN_FILE}; use an empty directory")
    write_json_atomic(plan_path, info)


@contextmanager
def claim_shards(out: Path, shards: range) -> Iterator[None]:
    """Hold ``shards`` of the dataset in ``out`` for this ``gen`` while it writes them, or refuse.

    One byte of ``out/.gen.lock`` per shard index, taken with a POSIX record lock (``fcntl.lockf``,
    released when the process ends, however it ends): a second ``gen`` on overlapping shards stops
    with a message saying so, while the disjoint ``--shards`` ranges of a job array run side by side.
    """
    path = out / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create {path.name} ({e.strerror}); choose a writable path") from e
    try:
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB, len(shards), shards.start, os.SEEK_SET)
        except OSError as e:  # EAGAIN or EACCES: held by another process
            raise ProjsynthError(
                f"--out {out}: another `projsynth gen` is writing shards there (some of "
                f"{shards.start}-{shards.stop - 1}; lock {path}); wait for it to finish, or give "
                "each run its own --shards range"
            ) from e
        yield
    finally:
        os.close(fd)


@contextmanager
def single_threaded() -> Iterator[None]:
    """One thread for BLAS/OpenMP and OpenCV while rendering: parallelism comes from worker processes.

    With their default pools (2 threads each here, OpenBLAS spinning between tiny 3 x N products),
    2 workers ran no faster than 1 (see docs/history/2026-11-log.md).
    """
    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(1):
            yield
    finally:
        cv2.setNumThreads(previous)


# a first cold compile of every kernel: about 50 s of CPU on the 2-core CI VM (numba, LLVM)
COMPILE_SECONDS = 50


def compile_kernels(plan: Plan, status: Callable[[str], None] | None = None) -> None:
    """Compile the per-pixel kernels once, here, when numba's cache does not hold them yet.

    Each worker process would otherwise compile them all by itself, side by side, with the progress
    bar at 0 % for minutes. One tiny sample of each (geometry family, photometric condition) of the
    plan calls the kernels with the argument types of the real samples (compiled code does not depend
    on the image size).
    """
    missing = uncompiled_kernels()
    if not missing:
        return
    first_run = len(missing) == len(KERNELS)  # else a kernel or two that earlier plans did not call: quick
    if status and first_run:
        status(f"compiling kernels (first run, ~{COMPILE_SECONDS} s)...")
    t0 = time.perf_counter()
    tiny = dataclasses.replace(plan, size=(32, 32))
    first: dict[tuple[str, str], int] = {}
    for k in range(len(tiny.transforms)):  # the first pair, first role: every transform once
        cfg = tiny.table.configs[sample_key(tiny, k)[2]]
        first.setdefault((cfg.family, cfg.condition), k)
    with single_threaded():
        images = source_images(tiny, 0)
        for k in first.values():
            make_sample(tiny, k, images)
    if status and first_run:
        status(f"kernels compiled in {time.perf_counter() - t0:.0f} s (cached for the next runs)")


_TICKS = None  # a worker's queue to the parent: one item per rendered sample


def _init_worker(ticks=None) -> None:
    global _TICKS
    _TICKS = ticks
    cv2.setNumThreads(1)
    threadpool_limits(1)  # for the life of the worker process


def _write_in_pool(jobs: list[tuple], workers: int, progress: Callable[[int], None] | None) -> None:
    """Shards in worker processes; their samples reported one by one as they are rendered."""
    ctx = mp.get_context("spawn")
    ticks = ctx.Queue()
    expected = sum(_shard_count(job[0], job[2], job[3]) for job in jobs)
    with ctx.Pool(workers, initializer=_init_worker, initargs=(ticks,)) as pool:
        pending = pool.map_async(_write_one_in_worker, jobs, chunksize=1)
        received = 0
        while received < expected:
            try:
                received += ticks.get(timeout=0.2)
                _report(progress, 1)
            except queue.Empty:
                if pending.ready():
                    if not pending.successful():
                        break
                    deadline = time.monotonic() + 2  # the last ticks may still be in the queue's pipe
                    while received < expected and time.monotonic() < deadline:
                        try:
                            received += ticks.get(timeout=0.1)
                            _report(progress, 1)
                        except queue.Empty:
                            pass
                    break
        pending.get()  # a worker's error, raised here


def _shard_count(plan: Plan, shard_size: int, j: int) -> int:
    return min(shard_size, plan.num_samples - j * shard_size)


def _write_one_in_worker(job: tuple) -> int:
    return _write_one(job, None if _TICKS is None else _TICKS.put)


def _write_one(job: tuple, tick: Callable[[int], None] | None = None) -> int:
    plan, out, shard_size, j, config_hash = job
    first = j * shard_size
    samples, cache = [], {}
    for k in range(first, first + _shard_count(plan, shard_size, j)):
        pair = sample_key(plan, k)[0]
        if pair not in cache:
            cache = {pair: source_images(plan, pair)}  # samples of a pair are consecutive
        samples.append(make_sample(plan, k, cache[pair]))
        if tick:
            tick(1)
    attrs = {
        "format_version": FORMAT_VERSION,
        "generator": f"projsynth {__version__}",
        "config_hash": config_hash,
        "seed": plan.seed,
        "shard_index": j,
        "first_sample": first,
        "split": plan.split,
        "table_version": plan.table.version,
        "libraries": library_versions(),
    }
    write_shard(out / shard_name(j), samples, attrs)
    return len(samples)


def _report(progress: Callable[[int], None] | None, n: int) -> None:
    if progress:
        progress(n)
