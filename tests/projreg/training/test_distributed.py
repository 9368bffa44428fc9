"""Multi-GPU correctness without a GPU: every collective's tensor on the process's device, each rank on
its own GPU. (The real NCCL run is bench/device_run.sh's, where a device is lent.)"""

import json
import math

import pytest
import torch
import torch.distributed as dist

import projreg.training.distributed as dd
import projreg.training.train as tr


def test_collective_tensors_must_live_on_the_process_device():
    cpu = torch.zeros(1)
    assert dd.checked_collective_tensor(cpu, torch.device("cpu")) is cpu
    with pytest.raises(RuntimeError, match="collective tensor on cpu, but this process runs on meta"):
        dd.checked_collective_tensor(cpu, torch.device("meta"))


def test_parameter_agreement_gathers_on_the_process_device(tmp_path, monkeypatch):
    # the bug NCCL would have hit: the checksum was all-gathered as a CPU tensor on a CUDA rank.
    # "meta" stands for a device that is not the CPU; the gather is recorded instead of run.
    seen = []

    def all_gather(out, tensor):
        seen.append(tensor.device)
        for o in out:
            o.copy_(tensor)

    monkeypatch.setattr(dist, "all_gather", all_gather)
    model = torch.nn.Linear(3, 2)
    dd.record_ddp_agreement(model, tmp_path, rank=1, world=2, device=torch.device("meta"))
    assert seen == [torch.device("meta")] and not (tmp_path / "ddp_params.json").exists()
    dd.record_ddp_agreement(model, tmp_path, rank=0, world=2, device=torch.device("cpu"))
    sums = json.loads((tmp_path / "ddp_params.json").read_text())
    expected = sum(float(p.detach().double().sum()) for p in model.parameters())
    assert sums == pytest.approx([expected, expected], rel=1e-12)


def test_each_rank_binds_its_own_gpu(monkeypatch):
    bound = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "set_device", bound.append)
    monkeypatch.setenv("LOCAL_RANK", "3")
    monkeypatch.setattr(torch.backends.cudnn, "benchmark", False)
    assert dd.process_device() == torch.device("cuda", 3) and bound == [torch.device("cuda", 3)]
    assert torch.backends.cudnn.benchmark


def test_without_cuda_the_process_runs_on_the_cpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert dd.process_device() == torch.device("cpu")


def test_interval_statistics_read_the_device_once_and_find_the_first_bad_step():
    stats = tr._Interval(torch.device("cpu"))
    one = torch.tensor(1.0)
    metrics = {"epe": torch.tensor(2.0), "px1": one, "px3": torch.tensor(0.5), "px5": torch.tensor(float("nan"))}
    stats.add(1, torch.tensor(4.0), metrics)
    stats.add(2, torch.tensor(2.0), metrics)
    row = stats.flush()
    assert math.isnan(row.pop("px5"))  # no step had a px5: not a zero
    assert row == {"loss": 3.0, "epe": 2.0, "px1": 1.0, "px3": 0.5, "bad_step": 0}
    stats.add(3, torch.tensor(float("inf")), metrics)
    stats.add(4, torch.tensor(float("nan")), metrics)
    assert stats.flush()["bad_step"] == 3
