"""examples/: the job-array and multi-node recipes run here at tiny sizes, and the manifest parses."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
BIN = Path(sys.executable).parent
TINY = {"PAIRS": "1", "TRANSFORMS": "0-3", "SHARD_SIZE": "2", "SIZE": "48x64", "SEED": "7", "SPLIT": "train"}


def _run(script: str, env: dict, timeout: int = 300) -> subprocess.CompletedProcess:
    env = os.environ | {"PATH": f"{BIN}:{os.environ['PATH']}", "OMP_NUM_THREADS": "1"} | env
    done = subprocess.run(
        ["bash", str(EXAMPLES / script)], env=env, cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    return done


def _gen_array(out: Path, tasks: int) -> None:
    for task in range(tasks):
        _run(
            "slurm_gen_array.sh",
            TINY | {"OUT": str(out), "SLURM_ARRAY_TASK_ID": str(task), "SLURM_ARRAY_TASK_COUNT": str(tasks)},
        )
    subprocess.run([BIN / "projsynth", "merge", str(out)], check=True, capture_output=True)


@pytest.fixture(scope="module")
def array_dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ex") / "train"
    _gen_array(out, tasks=3)
    return out


def test_job_array_writes_the_same_dataset_as_one_gen(array_dataset, tmp_path):
    one = tmp_path / "one"
    subprocess.run(
        [
            BIN / "projsynth",
            "gen",
            "--out",
            str(one),
            "--pairs",
            "1",
            "--transforms",
            "0-3",
            "--shard-size",
            "2",
            "--size",
            "48x64",
            "--seed",
            "7",
            "--quiet",
        ],
        check=True,
    )
    shards = sorted(p.name for p in array_dataset.glob("shard-*.h5"))
    assert len(shards) == 4  # 1 pair x 2 roles x 4 transforms, 2 per shard: tasks got 1, 1 and 2 shards
    for name in shards:
        assert (array_dataset / name).read_bytes() == (one / name).read_bytes(), name
    a, b = (json.loads((d / "manifest.json").read_text()) for d in (array_dataset, one))
    assert a["shards"] == b["shards"]
    subprocess.run([BIN / "projsynth", "verify", str(array_dataset), "--quiet"], check=True, capture_output=True)


def test_more_array_tasks_than_shards_leave_the_extra_tasks_idle(tmp_path):
    _gen_array(tmp_path / "d", tasks=6)  # 4 shards: two tasks have nothing to do and succeed
    assert len(list((tmp_path / "d").glob("shard-*.h5"))) == 4


def test_array_script_outside_slurm_names_the_missing_variable():
    done = subprocess.run(
        ["bash", str(EXAMPLES / "slurm_gen_array.sh")],
        capture_output=True,
        text=True,
        env={k: v for k, v in os.environ.items() if not k.startswith("SLURM_")},
    )
    assert done.returncode != 0 and "SLURM_ARRAY_TASK_ID" in done.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_multinode_script_trains_with_two_processes_on_one_node(array_dataset, tmp_path):
    run = tmp_path / "run"
    env = {
        "DATA": str(array_dataset),
        "VAL": str(array_dataset),
        "RUN": str(run),
        "MODEL": "small",
        "STEPS": "2",
        "SCHEDULE": "10",
        "WARMUP": "1",
        "BATCH": "1",
        "WORKERS": "0",
        "NNODES": "1",
        "NPROC_PER_NODE": "2",
        "HEAD": "127.0.0.1",
        "PORT": str(_free_port()),
        "LAUNCH": "env",
        "EXTRA": "--crop none",
    }
    _run("slurm_train_multinode.sh", env)
    sums = json.loads((run / "ddp_params.json").read_text())
    assert len(sums) == 2 and sums[0] == sums[1]
    assert torch.load(run / "checkpoints" / "last.pt", weights_only=True)["step"] == 2
    _run("slurm_train_multinode.sh", env | {"STEPS": "3", "RESUME": "1", "PORT": str(_free_port())})
    assert torch.load(run / "checkpoints" / "last.pt", weights_only=True)["step"] == 3


def test_kubernetes_job_runs_the_array_script_with_its_variables():
    yaml = pytest.importorskip("yaml")
    job = yaml.safe_load((EXAMPLES / "k8s_gen_indexed_job.yaml").read_text())
    spec = job["spec"]
    assert job["kind"] == "Job" and spec["completionMode"] == "Indexed"
    container = spec["template"]["spec"]["containers"][0]
    env = {e["name"]: e["value"] for e in container["env"]}
    assert env["SLURM_ARRAY_TASK_COUNT"] == str(spec["completions"])
    script = container["args"][0]
    assert "SLURM_ARRAY_TASK_ID=$JOB_COMPLETION_INDEX" in script and "examples/slurm_gen_array.sh" in script
    read = (EXAMPLES / "slurm_gen_array.sh").read_text()
    assert all(f"${{{name}" in read for name in env), "every variable the Job sets is one the script reads"
