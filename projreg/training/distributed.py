"""Training on several processes (``torchrun``): which device a rank runs on, collective tensors kept on
it, and a record that the ranks' parameters agree after training."""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
import torch.distributed as dist


def launched_by_torchrun() -> bool:
    """Whether ``torchrun`` started this process: it then joins a process group, even as the only rank
    (``--nproc_per_node 1`` exercises the multi-GPU code on one GPU)."""
    return "TORCHELASTIC_RUN_ID" in os.environ and "WORLD_SIZE" in os.environ


def process_device() -> torch.device:
    """This process's device: ``cuda:LOCAL_RANK`` (made current, cuDNN autotuning and TF32 matmuls on)
    when CUDA is available, else the CPU. Under ``torchrun`` every rank gets its own GPU."""
    if not torch.cuda.is_available():
        return torch.device("cpu")
    device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    torch.cuda.set_device(device)
    torch.backends.cudnn.benchmark = True
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    return device


def cuda_or_none(device: torch.device) -> torch.device | None:
    return device if device.type == "cuda" else None


def checked_collective_tensor(tensor: torch.Tensor, device: torch.device) -> torch.Tensor:
    """``tensor`` if it lives on the process's ``device``; NCCL takes CUDA tensors only, so a collective
    on any other device is a bug that only a multi-GPU run would show."""
    if tensor.device != device:
        raise RuntimeError(f"collective tensor on {tensor.device}, but this process runs on {device}")
    return tensor


def record_ddp_agreement(model: torch.nn.Module, out: Path, rank: int, world: int, device: torch.device) -> None:
    """Every rank's parameter checksum, gathered to rank 0 (``ddp_params.json``): DDP keeps them equal."""
    total = torch.stack([p.detach().double().sum() for p in model.parameters()]).sum().reshape(1).to(device)
    gathered = [torch.zeros_like(total) for _ in range(world)]
    dist.all_gather(gathered, checked_collective_tensor(total, device))
    if rank == 0:
        (out / "ddp_params.json").write_text(json.dumps([float(g) for g in gathered]))
