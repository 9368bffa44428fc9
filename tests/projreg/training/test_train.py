import csv
import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest
import torch
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.cli import app
from projreg.model.checkpoint import export_checkpoint, load_checkpoint
from projreg.training.train import TrainConfig, train

from ..conftest import make_shards


def _cfg(data, out, **kw):
    base = {
        "data": [str(data)],
        "out": str(out),
        "model": "small",
        "steps": 60,
        "batch_size": 2,
        "seed": 3,
        "workers": 0,
        "crop": None,
        "log_every": 1,
        "ckpt_every": 10,
        "val_every": 1000,
    }
    return TrainConfig(**(base | kw))


def _losses(run):
    with open(run / "metrics.csv", newline="") as f:
        return {int(r["step"]): float(r["loss"]) for r in csv.DictReader(f) if r["kind"] == "train"}


def test_thirty_steps_resumed_to_sixty_equal_sixty_and_loss_falls(tiny_train, tmp_path):
    full = tmp_path / "full"
    train(_cfg(tiny_train, full))
    part = tmp_path / "part"
    train(_cfg(tiny_train, part, steps=30))
    train(_cfg(tiny_train, part, steps=60), resume=True)
    a, b = _losses(full), _losses(part)
    assert sorted(b) == list(range(1, 61))
    for s in range(31, 61):
        assert abs(a[s] - b[s]) < 1e-4, (s, a[s], b[s])
    first, last = sum(a[s] for s in range(1, 11)) / 10, sum(a[s] for s in range(51, 61)) / 10
    assert last < 0.7 * first, (first, last)
    ck = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    assert ck["step"] == 60 and set(ck) >= {"model", "optimizer", "scheduler", "rng", "model_config"}


def test_resume_refuses_a_different_schedule(tiny_train, tmp_path):
    train(_cfg(tiny_train, tmp_path / "r", steps=2))
    with pytest.raises(ProjregError, match="--schedule-steps"):
        train(_cfg(tiny_train, tmp_path / "r", steps=4, schedule_steps=500), resume=True)


def test_no_ssjm_trains_and_records_ablation(tiny_train, tmp_path):
    summary = train(_cfg(tiny_train, tmp_path / "r", steps=4, use_ssjm=False))
    assert summary["step"] == 4
    assert load_checkpoint(tmp_path / "r" / "checkpoints" / "last.pt")["model_config"]["use_ssjm"] is False


def test_validation_rows_and_best_checkpoint(tiny_train, tiny_val, tmp_path):
    other = make_shards(tmp_path / "val48", size=(48, 64), split="val", transforms="10")  # validated one by one
    train(_cfg(tiny_train, tmp_path / "r", steps=4, val=[str(tiny_val), str(other)], val_every=2))
    with open(tmp_path / "r" / "metrics.csv", newline="") as f:
        val = [r for r in csv.DictReader(f) if r["kind"] == "val"]
    assert [int(r["step"]) for r in val] == [2, 4]
    assert all(float(r["epe"]) > 0 for r in val)
    assert (tmp_path / "r" / "checkpoints" / "best.pt").exists()


@pytest.mark.parametrize(("option", "value"), [("val_every", 0), ("val_samples", 0)])
def test_validation_cadence_and_size_must_be_positive(tiny_train, tiny_val, tmp_path, option, value):
    with pytest.raises(ProjregError, match=f"--{option.replace('_', '-')} must be >= 1"):
        train(_cfg(tiny_train, tmp_path / "r", steps=4, val=[str(tiny_val)], **{option: value}))
    assert not (tmp_path / "r").exists()


def test_config_json_records_every_resume(tiny_train, tmp_path, monkeypatch):
    run = tmp_path / "r"
    for steps, argv in ((2, ["first"]), (3, ["second"]), (4, ["third"])):
        monkeypatch.setattr(sys, "argv", argv)
        train(_cfg(tiny_train, run, steps=steps), resume=steps > 2)
    info = json.loads((run / "config.json").read_text())
    assert info["command"] == ["first"] and info["resumed_with"] == [["second"], ["third"]]


def test_refuses_existing_run_without_resume_and_resume_without_run(tiny_train, tmp_path):
    train(_cfg(tiny_train, tmp_path / "r", steps=2))
    with pytest.raises(ProjregError, match="--resume"):
        train(_cfg(tiny_train, tmp_path / "r", steps=2))
    with pytest.raises(ProjregError, match="--resume"):
        train(_cfg(tiny_train, tmp_path / "new", steps=2), resume=True)


def test_missing_dataset_is_one_clear_error(tmp_path):
    with pytest.raises(ProjregError, match="nowhere"):
        train(_cfg(tmp_path / "nowhere", tmp_path / "r", steps=2))
    assert not (tmp_path / "r").exists()  # nothing written before the data is known to be readable


def test_kill_9_then_resume_matches_uninterrupted(tiny_train, tmp_path):
    options = "--steps 40 --batch-size 2 --seed 3 --workers 0 --crop none --ckpt-every 5 --quiet".split()
    args = [sys.executable, "-m", "projreg.cli", "train", "--data", str(tiny_train), *options]
    ref = tmp_path / "ref"
    subprocess.run(args + ["--out", str(ref)], check=True)
    run = tmp_path / "run"
    proc = subprocess.Popen(args + ["--out", str(run)])
    deadline = time.time() + 120
    while time.time() < deadline and not (run / "checkpoints" / "last.pt").exists():
        time.sleep(0.05)
    time.sleep(0.3)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    subprocess.run(args + ["--out", str(run), "--resume"], check=True)
    a = torch.load(ref / "checkpoints" / "last.pt", weights_only=True)["model"]
    b = torch.load(run / "checkpoints" / "last.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def _torchrun_train(data, run, options: str) -> subprocess.CompletedProcess:
    """``projreg train --data DATA --out RUN OPTIONS`` under ``torchrun`` with two CPU processes."""
    torchrun = [sys.executable, *"-m torch.distributed.run --standalone --nproc_per_node 2 -m projreg.cli".split()]
    env = os.environ | {"OMP_NUM_THREADS": "1", "PYTHONFAULTHANDLER": "1"}  # an abort shows every thread's stack
    args = ["train", "--data", str(data), "--out", str(run), *options.split()]
    return subprocess.run(torchrun + args, env=env, timeout=300, capture_output=True, text=True)


def test_torchrun_two_cpu_processes_agree_on_parameters(tiny_train, tmp_path):
    run = tmp_path / "ddp"
    done = _torchrun_train(tiny_train, run, "--steps 3 --batch-size 1 --workers 0 --crop none")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-6000:]
    assert done.stderr.count(f"{run}: step 3, loss ") == 1  # rank 0 alone prints (and draws the bar)
    sums = __import__("json").loads((run / "ddp_params.json").read_text())
    assert len(sums) == 2 and sums[0] == sums[1]
    assert torch.load(run / "checkpoints" / "last.pt", weights_only=True)["step"] == 3


def test_sigint_stops_after_the_step_in_flight_with_a_checkpoint_and_resume_continues(tiny_train, tmp_path):
    def ctrl_c_at_step_3(step: int, loss: float) -> None:
        if step == 3:
            os.kill(os.getpid(), signal.SIGINT)

    run, ref = tmp_path / "run", tmp_path / "ref"
    before = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN in a background job
    summary = train(_cfg(tiny_train, run, steps=8, ckpt_every=100), progress=ctrl_c_at_step_3)
    assert summary["interrupted"] == "SIGINT" and summary["step"] == 3 and summary["steps_run"] == 3
    assert load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 3  # before the first --ckpt-every
    assert signal.getsignal(signal.SIGINT) is before  # the handlers are restored
    train(_cfg(tiny_train, ref, steps=6, ckpt_every=100))
    train(_cfg(tiny_train, run, steps=6, ckpt_every=100), resume=True)
    a = load_checkpoint(ref / "checkpoints" / "last.pt")["model"]
    b = load_checkpoint(run / "checkpoints" / "last.pt")["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_train_summary_is_rounded_and_a_no_op_resume_says_so(tiny_train, tiny_val, tmp_path):
    args = ["train", "--data", str(tiny_train), "--val", str(tiny_val), "--out", str(tmp_path / "r")]
    args += "--steps 2 --batch-size 1 --workers 0 --crop none --val-every 2 --quiet".split()
    result = CliRunner().invoke(app, args[:-1])
    assert result.exit_code == 0, result.stderr
    line = result.stderr.rsplit("\r", 1)[-1].strip().splitlines()[-1]
    loss, epe = re.fullmatch(rf"{tmp_path / 'r'}: step 2, loss (\S+), best val EPE (\S+) px", line).groups()
    assert len(loss.replace(".", "").lstrip("0")) <= 3 and len(epe.replace(".", "").lstrip("0")) <= 3  # 3 digits
    again = CliRunner().invoke(app, [*args[:-1], "--resume"])
    assert again.exit_code == 0, again.stderr
    assert f"already at step 2 (--steps); nothing to train, best val EPE {epe} px" in again.stderr
    assert "nan" not in again.stderr


def test_torchrun_worker_error_is_one_line_and_exit_2(tiny_train, tmp_path):
    run = tmp_path / "ddp"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.pt").write_bytes(b"a run already here")
    done = _torchrun_train(tiny_train, run, "--steps 3 --workers 0 --crop none --quiet")
    assert done.returncode != 0
    assert f"projreg: error: --out {run}: already holds a run" in done.stderr
    assert "exitcode  : 2" in done.stderr and "Fatal Python error" not in done.stderr
    assert (run / "checkpoints" / "last.pt").read_bytes() == b"a run already here"


@pytest.mark.parametrize("log_every", [1, 10])  # the check reads the device once per interval
def test_non_finite_loss_stops_and_keeps_last_good_checkpoint(tiny_train, tmp_path, monkeypatch, log_every):
    import projreg.training.train as tr

    real = tr.sequence_loss
    calls = {"n": 0}

    def poisoned(preds, flow, valid, gamma):
        calls["n"] += 1
        loss, stats = real(preds, flow, valid, gamma=gamma)
        return (loss * float("nan") if calls["n"] == 7 else loss), stats

    monkeypatch.setattr(tr, "sequence_loss", poisoned)
    with pytest.raises(ProjregError, match="non-finite loss at step 7"):
        train(_cfg(tiny_train, tmp_path / "r", steps=20, ckpt_every=5, log_every=log_every))
    ck = load_checkpoint(tmp_path / "r" / "checkpoints" / "last.pt")
    assert ck["step"] == 5 and all(torch.isfinite(v).all() for v in ck["model"].values())


def test_corrupt_shard_inside_a_loader_worker_is_one_line(tiny_train, tmp_path):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(tiny_train, broken)
    for shard in broken.glob("shard-*.h5"):
        shard.write_bytes(b"not hdf5")
    with pytest.raises(ProjregError) as info:
        train(_cfg(broken, tmp_path / "r", steps=2, workers=1))
    assert "\n" not in str(info.value) and "shard-0000" in str(info.value)


def test_resume_refuses_a_different_crop(tiny_train, tmp_path):
    train(_cfg(tiny_train, tmp_path / "r", steps=2))
    with pytest.raises(ProjregError, match="--crop"):
        train(_cfg(tiny_train, tmp_path / "r", steps=4, crop=(32, 48)), resume=True)


def test_activation_checkpointing_changes_memory_not_results(tiny_train, tmp_path):
    """Recomputing attention in backward is an exact trade: same losses and weights after 4 steps."""
    runs = {}
    for flag in (True, False):
        train(_cfg(tiny_train, tmp_path / str(flag), steps=4, activation_checkpointing=flag))
        runs[flag] = (_losses(tmp_path / str(flag)), load_checkpoint(tmp_path / str(flag) / "checkpoints" / "last.pt"))
    assert runs[True][0] == pytest.approx(runs[False][0], abs=1e-5)
    for name, w in runs[True][1]["model"].items():
        torch.testing.assert_close(w, runs[False][1]["model"][name], atol=1e-5, rtol=1e-4, msg=name)


def test_export_keeps_weights_and_provenance_and_drops_optimizer(tiny_ckpt, tmp_path):
    out = tmp_path / "deploy.pt"
    result = CliRunner().invoke(app, ["export", "--checkpoint", str(tiny_ckpt), "--out", str(out)])
    assert result.exit_code == 0, result.stderr
    full, slim = load_checkpoint(tiny_ckpt), load_checkpoint(out)
    assert set(slim) == {"model", "model_config", "step", "best_epe", "train_config", "version"}
    assert slim["step"] == full["step"] and slim["model_config"] == full["model_config"]
    for name, w in full["model"].items():
        assert torch.equal(slim["model"][name], w), name
    assert out.stat().st_size < 0.5 * tiny_ckpt.stat().st_size  # AdamW's two moments are gone


def test_export_of_a_non_checkpoint_is_one_line(tmp_path, one_line_error):
    bad = tmp_path / "notes.pt"
    bad.write_bytes(b"not a checkpoint")
    result = CliRunner().invoke(app, ["export", "--checkpoint", str(bad), "--out", str(tmp_path / "x.pt")])
    one_line_error(result, bad)
    assert not (tmp_path / "x.pt").exists()


def test_export_refuses_to_overwrite_its_source_and_resume_refuses_an_export(tiny_train, tmp_path, one_line_error):
    run = tmp_path / "r"
    train(_cfg(tiny_train, run, steps=2))
    last = run / "checkpoints" / "last.pt"
    before = last.read_bytes()
    one_line_error(
        CliRunner().invoke(app, ["export", "--checkpoint", str(last), "--out", str(last)]), last, "another file"
    )
    assert last.read_bytes() == before  # the training state survives
    export_checkpoint(last, tmp_path / "slim.pt")
    (tmp_path / "slim.pt").replace(last)  # a user copies an export over last.pt
    with pytest.raises(ProjregError, match=r"lacks optimizer, scheduler, rng .*resume needs the last.pt"):
        train(_cfg(tiny_train, run, steps=4), resume=True)


def test_resume_accepts_the_same_dataset_by_another_path(tiny_train, tmp_path, monkeypatch):
    run = tmp_path / "r"
    train(_cfg(tiny_train, run, steps=2))
    monkeypatch.chdir(tiny_train.parent)
    assert train(_cfg(f"./{tiny_train.name}", run, steps=3), resume=True)["step"] == 3


@pytest.mark.parametrize("damage", ["nan weight", "wrong shape"])
def test_checkpoint_whose_weights_are_unusable_is_one_line(tiny_ckpt, tmp_path, one_line_error, damage):
    ck = load_checkpoint(tiny_ckpt)
    name = next(k for k, v in ck["model"].items() if v.is_floating_point() and v.ndim == 2)
    if damage == "nan weight":
        ck["model"][name] = ck["model"][name].clone().fill_(float("nan"))
    else:
        ck["model"][name] = ck["model"][name][:, :-1].clone()
    bad = tmp_path / "bad.pt"
    torch.save(ck, bad)
    result = CliRunner().invoke(app, ["export", "--checkpoint", str(bad), "--out", str(tmp_path / "x.pt")])
    line = one_line_error(result, bad, name)
    assert ("non-finite" in line) == (damage == "nan weight")
    assert not (tmp_path / "x.pt").exists()


def test_init_starts_from_a_checkpoints_weights_with_a_fresh_schedule(tiny_train, tiny_ckpt, tmp_path):
    start = load_checkpoint(tiny_ckpt)["model"]
    train(_cfg(tiny_train, tmp_path / "ft", steps=1, lr=1e-12, init=str(tiny_ckpt)))
    ck = load_checkpoint(tmp_path / "ft" / "checkpoints" / "last.pt")
    assert ck["step"] == 1 and ck["train_config"]["init"] == str(tiny_ckpt)
    for name, value in start.items():  # one step at lr 1e-12 from the init, not from a seeded initialisation
        assert torch.allclose(ck["model"][name].float(), value.float(), atol=1e-6), name
    fresh = load_checkpoint(tiny_ckpt)["model"]
    train(_cfg(tiny_train, tmp_path / "seeded", steps=1, lr=1e-12, seed=11))
    seeded = load_checkpoint(tmp_path / "seeded" / "checkpoints" / "last.pt")["model"]
    assert any(not torch.allclose(seeded[k].float(), fresh[k].float(), atol=1e-3) for k in fresh)


def test_init_of_another_architecture_or_a_changed_init_on_resume_is_refused(tiny_train, tiny_ckpt, tmp_path):
    with pytest.raises(ProjregError, match=r"--init .*differs from --model's in use_ssjm"):
        train(_cfg(tiny_train, tmp_path / "r", steps=1, use_ssjm=False, init=str(tiny_ckpt)))
    assert not (tmp_path / "r").exists()  # nothing written
    train(_cfg(tiny_train, tmp_path / "r", steps=1, init=str(tiny_ckpt)))
    with pytest.raises(ProjregError, match="--init"):
        train(_cfg(tiny_train, tmp_path / "r", steps=2), resume=True)


def test_init_through_the_cli_as_a_user_fine_tunes(tiny_train, tiny_ckpt, tmp_path, one_line_error):
    args = ["train", "--data", tiny_train, *"--steps 2 --batch-size 1 --workers 0 --crop none".split()]
    args += ["--init", tiny_ckpt, *"--lr 1e-4 --schedule-steps 2 --warmup-steps 1 -q".split()]
    run = tmp_path / "ft"
    result = CliRunner().invoke(app, [str(a) for a in [*args, "--out", run]])
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert json.loads((run / "config.json").read_text())["train_config"]["init"] == str(tiny_ckpt)
    other = tmp_path / "other"
    result = CliRunner().invoke(app, [str(a) for a in [*args, "--out", other, "--no-ssjm"]])
    one_line_error(result, "--init", "use_ssjm")
    assert not other.exists()


def test_gamma_through_the_cli_weighs_the_coarse_predictions(tiny_train, tmp_path):
    """--gamma reaches the loss: from the same weights and batch, the first step's loss is larger when the
    coarse predictions weigh as much as the last (every term is positive), and the run records it."""
    args = ["train", "--data", tiny_train, *"--steps 1 --batch-size 1 --workers 0 --crop none --seed 5 -q".split()]
    losses = {}
    for gamma in ("1", "0.5"):
        run = tmp_path / f"g{gamma}"
        result = CliRunner().invoke(app, [str(a) for a in [*args, "--gamma", gamma, "--out", run]])
        assert result.exit_code == 0, (result.stderr, result.exception)
        assert json.loads((run / "config.json").read_text())["train_config"]["gamma"] == float(gamma)
        with open(run / "metrics.csv", newline="") as f:
            losses[gamma] = float(next(r for r in csv.DictReader(f) if r["kind"] == "train")["loss"])
    assert losses["1"] > 1.2 * losses["0.5"], losses


def test_init_reference_without_a_shipped_model_names_the_option(tiny_train, tmp_path, monkeypatch):
    monkeypatch.setattr("projreg.model.checkpoint.reference_checkpoint", lambda: None)
    with pytest.raises(ProjregError, match="--init reference: no shipped reference model"):
        train(_cfg(tiny_train, tmp_path / "r", steps=1, init="reference"))
    assert not (tmp_path / "r").exists()
