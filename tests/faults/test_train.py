"""Defects 3, 4, 8, 9 and 13: `projreg train` with bad options, a diverging run and a bad first batch."""

import math

import pytest
import torch

from projreg import ProjregError
from projreg.training.train import TrainConfig, train
from projsynth.dataset.shards import shard_name

FAST = ["--steps", "1", "--batch-size", "2", "--crop", "none", "--workers", "0", "-q"]


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--seed", "-1", "--seed must be in 0..4294967295"),
        ("--seed", str(2**32), "--seed must be in 0..4294967295"),
        ("--seed", str(2**64), "--seed must be in 0..4294967295"),
        ("--lr", "inf", "--lr must be finite"),
        ("--lr", "nan", "--lr must be finite"),
        ("--gamma", "0", "--gamma must be in (0, 1]"),
        ("--gamma", "1.5", "--gamma must be in (0, 1]"),
        ("--batch-size", "100000", "--batch-size 100000 exceeds the 32 samples of --data"),
    ],
)
def test_a_bad_option_is_refused_before_anything_is_written(probe, dataset_d, tmp_path, option, value, message):
    out = tmp_path / "run"
    args = [a for a in FAST if a not in ("--batch-size", "2")] if option == "--batch-size" else FAST
    probe.error(probe.projreg("train", "--data", dataset_d, "--out", out, option, value, *args), message)
    assert not out.exists()


def test_an_empty_out_is_refused(probe, dataset_d, tmp_path):
    probe.error(
        probe.process("projreg", "train", "--data", dataset_d, "--out", "", *FAST, cwd=tmp_path), "--out", "empty"
    )
    assert list(tmp_path.iterdir()) == []


def test_a_diverging_run_never_writes_a_non_finite_checkpoint(dataset_d, tmp_path, monkeypatch):
    """The probe's ``--lr inf`` (refused up front now; let through here to make the weights diverge):
    before the fix, the first step's Inf weights were written to last.pt, then named as "the last good
    checkpoint"."""
    monkeypatch.setattr(TrainConfig, "validate", lambda self: None)
    out = tmp_path / "run"
    cfg = TrainConfig(
        data=[str(dataset_d)],
        out=str(out),
        steps=3,
        schedule_steps=3,
        warmup_steps=0,
        batch_size=1,
        lr=math.inf,
        crop=None,
        workers=0,
        ckpt_every=1,
        log_every=1,
    )
    with pytest.raises(ProjregError, match="non-finite") as info:
        train(cfg)
    message, last = str(info.value), out / "checkpoints" / "last.pt"
    assert (str(last) in message) == last.exists()
    assert last.exists() or "no checkpoint was written" in message
    for path in (out / "checkpoints").glob("*.pt"):
        ckpt = torch.load(path, weights_only=True)
        tensors = [*ckpt["model"].values(), *(t for s in ckpt["optimizer"]["state"].values() for t in s.values())]
        assert all(torch.isfinite(t).all() for t in tensors if t.is_floating_point()), path


def test_a_bad_first_batch_leaves_out_untouched(probe, d_copy, tmp_path):
    for j in range(4):
        probe.flip_chunks(d_copy / shard_name(j), "captured")
    out = tmp_path / "run"
    probe.error(probe.projreg("train", "--data", d_copy, "--out", out, *FAST), "unreadable")
    assert not out.exists()  # before the fix: config.json, metrics.csv and an empty checkpoints/
    probe.error(probe.projreg("train", "--data", d_copy, "--out", out, *FAST, "--resume"), "does not exist")
