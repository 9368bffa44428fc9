"""``projreg train``: AdamW + OneCycle, gamma-weighted sequence L1 on valid pixels, exact resume.

Run directory::

    RUN/config.json            resolved config, versions, command line
    RUN/metrics.csv            one row per logged step (kind=train) and per validation (kind=val)
    RUN/checkpoints/last.pt    model, optimizer, scheduler, RNG states, step (atomic)
    RUN/checkpoints/best.pt    the model with the lowest validation EPE

Multi-GPU / multi-node: launch with ``torchrun``; each rank reads its own slice of the sample stream
and only rank 0 writes. Checkpoints contain only tensors and plain containers
(``torch.load(..., weights_only=True)``).
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import platform
import random
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader

from projsynth.errors import ProjsynthError
from projsynth.utils.files import write_atomic

from ..errors import ProjregError
from ..model.checkpoint import atomic_save, load_checkpoint, require_model, resolve_checkpoint
from ..model.net import SSJMFlow, build_model, count_parameters
from ..versions import __version__
from .data import Augment, ShardDataset, StreamSampler
from .distributed import (
    checked_collective_tensor,
    cuda_or_none,
    launched_by_torchrun,
    process_device,
    record_ddp_agreement,
)
from .loss import sequence_loss
from .validate import evaluate

CSV_FIELDS = ("step", "kind", "loss", "epe", "s0-10", "s10-40", "s40+", "px1", "px3", "px5", "lr", "samples_per_s")


@dataclass(frozen=True)
class TrainConfig:
    data: list[str]
    out: str
    val: list[str] = field(default_factory=list)
    model: str = "small"
    use_ssjm: bool = True
    steps: int = 15000  # where this invocation stops
    schedule_steps: int = 15000  # the OneCycle length (the paper's 15,000 iterations)
    warmup_steps: int = 100
    batch_size: int = 8
    lr: float = 4e-4
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    gamma: float = 0.9
    seed: int = 0
    workers: int = 2
    crop: tuple[int, int] | None = (256, 320)
    log_every: int = 10
    val_every: int = 500
    val_samples: int = 64
    ckpt_every: int = 100
    amp: bool = False  # bf16 autocast, CUDA only
    compile: bool = False
    activation_checkpointing: bool = False  # on: ~15% slower steps, less memory (small, 256x320, batch 8:
    # 2.9 instead of 4.0 GiB peak RSS on the CPU); for large crops or batches
    init: str | None = None  # a checkpoint (or "reference") whose weights start the run: a fine-tune

    def validate(self) -> None:
        checks = [
            (self.steps >= 1, "--steps must be >= 1"),
            (self.batch_size >= 1, "--batch-size must be >= 1"),
            (
                self.steps <= self.schedule_steps,
                f"--steps {self.steps} exceeds --schedule-steps {self.schedule_steps}; raise --schedule-steps",
            ),
            (0 <= self.warmup_steps < self.schedule_steps, "--warmup-steps must be in [0, --schedule-steps)"),
            (0 < self.lr < math.inf, "--lr must be finite and > 0"),
            (0 <= self.seed < 2**32, f"--seed must be in 0..{2**32 - 1} (numpy's seed range)"),
            (self.workers >= 0, "--workers must be >= 0"),
            (self.ckpt_every >= 1 and self.log_every >= 1, "--ckpt-every and --log-every must be >= 1"),
            (self.val_every >= 1 or not self.val, "--val-every must be >= 1"),
            (self.val_samples >= 1, "--val-samples must be >= 1"),
            (0 < self.gamma <= 1, "--gamma must be in (0, 1]"),
            (self.init is None or self.init.strip(), "--init: empty; give a checkpoint file or `reference`"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ProjregError(msg)


def initial_weights(spec: str, model: SSJMFlow) -> dict:
    """The weights of checkpoint ``spec`` (``reference``: the shipped model) for ``model``, which must
    be the same architecture; only the weights are taken (a fresh optimizer and schedule follow)."""
    try:
        path = resolve_checkpoint(spec)
    except ProjregError:
        raise ProjregError(f"--init {spec}: no shipped reference model here; pass a checkpoint file") from None
    ckpt = require_model(load_checkpoint(path), path)
    if ckpt["model_config"] != model.config:
        diff = sorted(
            k for k in {*ckpt["model_config"], *model.config} if ckpt["model_config"].get(k) != model.config.get(k)
        )
        raise ProjregError(
            f"--init {spec}: its network differs from --model's in {', '.join(diff)}; "
            "pass the --model (and --no-ssjm) it was trained with"
        )
    return ckpt["model"]


def _next_batch(batches) -> dict:
    """The next batch; an error inside a loader worker becomes one line (torch wraps it in a traceback)."""
    try:
        return next(batches)
    except ProjregError as e:
        lines = [line for line in str(e).splitlines() if line.strip()]
        raise ProjregError(lines[-1].removeprefix("projreg.ProjregError: ") if lines else str(e)) from None


def _rng_state() -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state()[1].tolist(), "python": random.getstate()[1]}


def _set_rng_state(s: dict) -> None:
    torch.set_rng_state(s["torch"])
    st = np.random.get_state()
    np.random.set_state((st[0], np.array(s["numpy"], dtype=np.uint32), *st[2:]))
    random.setstate((3, tuple(s["python"]), None))


class _Log:
    """metrics.csv, truncated to ``step`` on resume so the log matches the checkpoint."""

    def __init__(self, path: Path, resume_step: int | None, enabled: bool):
        self.path, self.enabled = path, enabled
        if not enabled:
            return
        rows = []
        if resume_step is not None and path.exists():
            with open(path, newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, CSV_FIELDS)
            w.writeheader()
            w.writerows(rows)
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(path.parent / "tensorboard"))
        except ImportError:
            self.tb = None

    def write(self, row: dict) -> None:
        if not self.enabled:
            return
        with open(self.path, "a", newline="") as f:
            csv.DictWriter(f, CSV_FIELDS).writerow({k: row.get(k, "") for k in CSV_FIELDS})
        if self.tb is not None:
            for k, v in row.items():
                if isinstance(v, float) and math.isfinite(v):
                    self.tb.add_scalar(f"{row['kind']}/{k}", v, row["step"])
            self.tb.flush()  # on disk like the CSV row: a torchrun worker ends with os._exit


_RESUME_KEYS = ("model", "optimizer", "scheduler", "rng", "step", "best_epe", "train_config")


def train(
    cfg: TrainConfig,
    *,
    resume: bool = False,
    progress: Callable[[int, float], None] | None = None,
    val_progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Train ``cfg.model`` on ``cfg.data``.

    SIGINT or SIGTERM (Ctrl-C, a scheduler's stop) ends the run after the step in flight, with
    ``last.pt`` written at that step (under torchrun the ranks agree at the next logged step); a
    second SIGINT stops at once, without a checkpoint.

    Args:
        progress: ``(step, loss)`` after each step.
        val_progress: ``(done, total)`` samples of each validation.

    Returns:
        ``step`` (final), ``loss`` (last step's; None when no step ran), ``best_epe`` (None without
        validation), ``steps_run`` (in this call), ``interrupted`` (the signal's name, or None).
    """
    with _StopSignal() as stop:
        return _train(cfg, resume, progress, val_progress, stop)


_RESUME_MUST_MATCH = (
    ("model", "--model"),
    ("use_ssjm", "--no-ssjm"),
    ("schedule_steps", "--schedule-steps"),
    ("warmup_steps", "--warmup-steps"),
    ("lr", "--lr"),
    ("batch_size", "--batch-size"),
    ("seed", "--seed"),
    ("data", "--data"),
    ("crop", "--crop"),
    ("gamma", "--gamma"),
    ("weight_decay", "weight decay"),
    ("grad_clip", "gradient clipping"),
    ("amp", "--amp"),
    ("init", "--init"),
)


@dataclass(frozen=True)
class _Process:
    """Where this process runs: its rank among ``world`` (0 of 1 without torchrun) and its device."""

    rank: int
    world: int
    distributed: bool
    device: torch.device


class _Run:
    """What a checkpoint holds: the model, its optimizer and schedule, the step and the best validation
    EPE; ``save`` writes it (never with non-finite weights), ``restore`` continues it exactly."""

    def __init__(self, cfg: TrainConfig, device: torch.device) -> None:
        self.cfg = cfg  # seeded before the model is built: the initial weights follow --seed
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        random.seed(cfg.seed)
        self.model = build_model(cfg.model, use_ssjm=cfg.use_ssjm).to(device)
        self.model.transformer.checkpointing = cfg.activation_checkpointing
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.sched = _schedule(self.opt, cfg)
        self.step, self.best = 0, float("inf")
        self.last_path = Path(cfg.out) / "checkpoints" / "last.pt"

    def restore(self) -> None:
        """Continue ``last.pt``: weights, optimizer, schedule, RNG states, step and best EPE."""
        path, cfg = self.last_path, self.cfg
        ck = load_checkpoint(path)
        missing = [k for k in _RESUME_KEYS if not isinstance(ck, dict) or k not in ck]
        if missing:
            raise ProjregError(
                f"--resume: {path} lacks {', '.join(missing)} (an exported checkpoint?); "
                "resume needs the last.pt that `projreg train` wrote"
            )
        old = ck["train_config"]
        for key, option in _RESUME_MUST_MATCH:
            if _plain(old.get(key), key) != _plain(getattr(cfg, key), key):
                raise ProjregError(
                    f"--resume: {path} was trained with {option} {old.get(key)}, not "
                    f"{getattr(cfg, key)}; resume with the same value"
                )
        if int(ck["step"]) > cfg.steps:
            raise ProjregError(f"--resume: {path} is already at step {ck['step']} > --steps {cfg.steps}")
        self.model.load_state_dict(ck["model"])
        self.opt.load_state_dict(ck["optimizer"])
        self.sched.load_state_dict(ck["scheduler"])
        _set_rng_state(ck["rng"])
        self.step, self.best = int(ck["step"]), float(ck["best_epe"])

    def save(self, path: Path) -> None:
        bad = _non_finite(self.model, self.opt)
        if bad is not None:
            raise ProjregError(
                f"non-finite {bad} after step {self.step} (--lr too high?); stopped without writing "
                f"{path.name}, {_last_good(self.last_path)}"
            )
        state = {
            "model": self.model.state_dict(),
            "model_config": self.model.config,
            "optimizer": self.opt.state_dict(),
            "scheduler": self.sched.state_dict(),
            "rng": _rng_state(),
            "step": self.step,
            "best_epe": self.best,
            "train_config": asdict(self.cfg),
            "version": __version__,
        }
        atomic_save(state, path)


def _batches(train_ds: ShardDataset, cfg: TrainConfig, step: int, rank: int, world: int, device: torch.device):
    """The sample stream from ``step`` on (this rank's slice of it); the first batch is read at once, so
    that a bad one leaves ``--out`` untouched."""
    sampler = StreamSampler(len(train_ds), cfg.seed, start=step * cfg.batch_size, rank=rank, world=world)
    loader = DataLoader(
        train_ds,
        batch_size=cfg.batch_size,
        sampler=sampler,
        num_workers=cfg.workers,
        pin_memory=device.type == "cuda",
        drop_last=True,
        worker_init_fn=_ignore_interrupts,
    )
    batches = iter(loader)
    return itertools.chain([_next_batch(batches)], batches)


def _make_out(out: Path, cfg: TrainConfig, model: SSJMFlow, resume: bool) -> None:
    try:
        (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjregError(f"--out {out}: cannot create ({e.strerror})") from e
    _write_config(out, cfg, model, resume)


def _train(
    cfg: TrainConfig,
    resume: bool,
    progress: Callable[[int, float], None] | None,
    val_progress: Callable[[int, int], None] | None,
    stop: _StopSignal,
) -> dict:
    cfg.validate()
    distributed = launched_by_torchrun()
    device = process_device()
    if distributed:  # NCCL wants the rank's GPU bound before the group exists (and every tensor on it)
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", device_id=cuda_or_none(device))
    rank, world = (dist.get_rank(), dist.get_world_size()) if distributed else (0, 1)
    # the data first: a bad --data or --val leaves --out untouched
    train_ds = ShardDataset([Path(p) for p in cfg.data], Augment(crop=cfg.crop))
    val_ds = ShardDataset([Path(p) for p in cfg.val], batched=False) if cfg.val else None
    if cfg.batch_size > len(train_ds):  # the stream would repeat samples within one batch, without bound
        raise ProjregError(f"--batch-size {cfg.batch_size} exceeds the {len(train_ds)} samples of --data; lower it")
    out = Path(cfg.out)
    run = _Run(cfg, device)
    if rank == 0 and not resume and run.last_path.exists():
        raise ProjregError(f"--out {out}: already holds a run; add --resume to continue it or pick a new --out")
    if resume and not run.last_path.exists():
        raise ProjregError(f"--resume: {run.last_path} does not exist; start without --resume")
    if resume:
        run.restore()
    elif cfg.init is not None:  # on resume the weights come from last.pt
        run.model.load_state_dict(initial_weights(cfg.init, run.model))
    batches = _batches(train_ds, cfg, run.step, rank, world, device)
    if rank == 0:
        _make_out(out, cfg, run.model, resume)
    log = _Log(out / "metrics.csv", run.step if resume else None, rank == 0)
    net = run.model
    if distributed:
        ids = [device.index] if device.type == "cuda" else None  # one GPU per process
        net = torch.nn.parallel.DistributedDataParallel(run.model, device_ids=ids)
    if cfg.compile:
        net = torch.compile(net)
    start = run.step
    proc = _Process(rank, world, distributed, device)
    last_loss = _loop(run, net, batches, val_ds, log, stop, proc, progress, val_progress)
    if stop.signal is not None and rank == 0:
        run.save(run.last_path)  # the state after the last finished step: --resume continues from it
    summary = {
        "step": run.step,
        "loss": None if run.step == start else last_loss,
        "best_epe": None if math.isinf(run.best) else run.best,
        "steps_run": run.step - start,
        "interrupted": stop.signal,
        "checkpoint": str(run.last_path),
    }
    if distributed:
        record_ddp_agreement(run.model, out, rank, world, device)
        dist.destroy_process_group()
    return summary


def _loop(
    run: _Run, net, batches, val_ds, log: _Log, stop: _StopSignal, proc: _Process, progress, val_progress
) -> float:
    """Optimiser steps until ``cfg.steps`` or a stop signal; the loss of the last logged step.

    The host reads the device once per log, validation or checkpoint step, not every step."""
    cfg, model, opt, sched = run.cfg, run.model, run.opt, run.sched
    rank, world, distributed, device = proc.rank, proc.world, proc.distributed, proc.device
    autocast = torch.autocast("cuda", dtype=torch.bfloat16, enabled=cfg.amp and device.type == "cuda")
    t0, seen, last_loss = time.perf_counter(), 0, float("nan")
    stats = _Interval(device)  # device-side sums: the host waits for the GPU once per log interval
    model.train()
    while run.step < cfg.steps and not stop.agreed(run.step, distributed, cfg.log_every, device):
        batch = _next_batch_unless_stopped(batches, stop)
        if batch is None:
            break
        batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
        with autocast:
            preds = net(batch["img0"], batch["img1"])  # uint8 images: the network normalises on the device
        loss, metrics = sequence_loss([p.float() for p in preds], batch["flow"], batch["valid"], gamma=cfg.gamma)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        sched.step()
        run.step += 1
        step = run.step
        seen += cfg.batch_size * world
        stats.add(step, loss.detach(), metrics)
        logging = step % cfg.log_every == 0 or step == cfg.steps
        validating = val_ds is not None and rank == 0 and (step % cfg.val_every == 0 or step == cfg.steps)
        if logging or validating or step % cfg.ckpt_every == 0:
            row = stats.flush(reset=logging)  # the one host sync of the interval
            bad_step = row.pop("bad_step")
            if bad_step:
                raise ProjregError(f"non-finite loss at step {bad_step}; stopped, {_last_good(run.last_path)}")
            last_loss = row["loss"]
            if logging:
                rate = seen / (time.perf_counter() - t0)
                log.write({"step": step, "kind": "train", **row, "lr": sched.get_last_lr()[0], "samples_per_s": rate})
            if validating:
                _validate(run, val_ds, log, device, val_progress)
            if rank == 0 and (step % cfg.ckpt_every == 0 or step == cfg.steps):
                run.save(run.last_path)
        if progress:
            progress(step, last_loss)
    return last_loss


def _validate(run: _Run, val_ds: ShardDataset, log: _Log, device: torch.device, val_progress) -> None:
    """Validation EPE on ``cfg.val_samples`` samples, logged; ``best.pt`` when it is the lowest yet."""
    res = evaluate(run.model, val_ds, device=device, limit=run.cfg.val_samples, progress=val_progress)
    run.model.train()
    log.write({"step": run.step, "kind": "val", **{k: res[k] for k in CSV_FIELDS if k in res}})
    if res["epe"] is not None and res["epe"] < run.best:
        run.best = res["epe"]
        run.save(Path(run.cfg.out) / "checkpoints" / "best.pt")


class _StopSignal:
    """SIGINT/SIGTERM during training: note it, let the step in flight finish, then stop with a checkpoint.

    The handlers are installed for the ``with`` block (main thread only: signals are delivered there)
    and the previous ones restored after it. A second SIGINT raises KeyboardInterrupt at once.
    """

    def __init__(self) -> None:
        self.signal: str | None = None
        self.previous: dict[int, object] = {}

    def __enter__(self) -> _StopSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.previous[sig] = signal.signal(sig, self._note)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)

    def _note(self, signum: int, frame: object) -> None:
        if self.signal is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name

    def agreed(self, step: int, distributed: bool, every: int, device: torch.device) -> bool:
        """Whether to stop before the next step. Under torchrun the ranks agree (a MAX all-reduce) at
        every ``every``-th step only, so that no rank stops alone and none pays a sync per step."""
        if not distributed:
            return self.signal is not None
        if step % every:
            return False
        flag = torch.tensor([float(self.signal is not None)], device=device)
        dist.all_reduce(checked_collective_tensor(flag, device), op=dist.ReduceOp.MAX)
        if flag.item() and self.signal is None:
            self.signal = "SIGTERM (another rank)"
        return bool(flag.item())


def _ignore_interrupts(worker_id: int) -> None:
    """DataLoader workers leave Ctrl-C to the main process, which finishes its step and checkpoints."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _next_batch_unless_stopped(batches, stop: _StopSignal) -> dict | None:
    """The next batch; None when a stop signal has also ended the loader's workers."""
    try:
        return _next_batch(batches)
    except (RuntimeError, ProjregError):
        if stop.signal is None:
            raise
        return None


def _non_finite(model: torch.nn.Module, opt: torch.optim.Optimizer) -> str | None:
    """The first weight or optimizer state tensor holding NaN or Inf, by name; None when all are finite."""
    for name, t in model.state_dict().items():
        if t.is_floating_point() and not torch.isfinite(t).all():
            return f"weight {name}"
    for state in opt.state.values():
        for name, t in state.items():
            if torch.is_tensor(t) and t.is_floating_point() and not torch.isfinite(t).all():
                return f"optimizer state {name}"
    return None


def _last_good(last_path: Path) -> str:
    """Where a stopped run can be resumed from: ``last.pt`` is never written with non-finite weights."""
    if last_path.exists():
        return f"the last good checkpoint is {last_path}"
    return "no checkpoint was written; lower --lr or check the data"


def _plain(value, key: str = ""):
    """Tuples and lists compare equal (a checkpoint stores the crop as a list); dataset paths compare
    resolved (``data`` and ``./data`` are the same dataset)."""
    if key == "data" and isinstance(value, tuple | list):
        return [str(Path(p).resolve()) for p in value]
    return list(value) if isinstance(value, tuple | list) else value


def _schedule(opt: torch.optim.Optimizer, cfg: TrainConfig) -> torch.optim.lr_scheduler.LRScheduler:
    """OneCycle over ``cfg.schedule_steps``: linear warm-up for ``warmup_steps``, then linear decay.

    It does not depend on ``cfg.steps`` (where a run stops), so stopping at 30 and resuming to 60 is
    the same run as going to 60 at once.
    """
    return torch.optim.lr_scheduler.OneCycleLR(
        opt,
        max_lr=cfg.lr,
        total_steps=cfg.schedule_steps + 1,
        pct_start=max(cfg.warmup_steps, 1) / cfg.schedule_steps,
        cycle_momentum=False,
        anneal_strategy="linear",
    )


def _write_config(out: Path, cfg: TrainConfig, model: SSJMFlow, resume: bool) -> None:
    info = {
        "train_config": asdict(cfg),
        "model_config": model.config,
        "parameters": count_parameters(model),
        "versions": {
            "projreg": __version__,
            "torch": torch.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "command": sys.argv,
        "resumed": resume,
    }
    path = out / "config.json"
    try:
        if resume and path.exists():  # keep the original, record the resume
            old = json.loads(path.read_text())
            before = old.get("resumed_with", [])
            before = [before] if before and isinstance(before[0], str) else before  # one resume, as 0.1 wrote it
            info = old | {"resumed_with": [*before, sys.argv]}  # every resume's command, in order
        write_atomic(path, (json.dumps(info, indent=1) + "\n").encode())
    except (OSError, ValueError, ProjsynthError) as e:
        raise ProjregError(f"{path}: cannot write the run config ({e})") from e


class _Interval:
    """Loss statistics summed on the device between two log lines (means over the steps this process
    ran since the previous line), and the first step whose loss was not finite; ``flush`` reads them to
    the host (one synchronisation) and, with ``reset``, starts a new interval."""

    KEYS = ("epe", "px1", "px3", "px5")

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self._reset()

    def _reset(self) -> None:
        self.sums = torch.zeros(1 + len(self.KEYS), dtype=torch.float64, device=self.device)
        self.counts = torch.zeros_like(self.sums)
        self.bad = torch.zeros((), dtype=torch.int64, device=self.device)

    def add(self, step: int, loss: torch.Tensor, metrics: dict[str, torch.Tensor]) -> None:
        values = torch.stack([loss.double(), *(metrics[k].double() for k in self.KEYS)])
        finite = torch.isfinite(values)  # a batch without valid pixels has no EPE: it does not count
        self.sums += torch.where(finite, values, 0.0)
        self.counts += finite
        self.bad = torch.where((self.bad == 0) & ~finite[0], step, self.bad)

    def flush(self, reset: bool = True) -> dict:
        means = (self.sums / self.counts).tolist()  # NaN where nothing counted
        row = dict(zip(("loss", *self.KEYS), means, strict=True)) | {"bad_step": int(self.bad)}
        if reset:
            self._reset()
        return row
