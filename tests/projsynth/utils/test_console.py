"""The console plumbing both command lines share (``projsynth.utils.console``)."""

import os
import subprocess
import sys
from pathlib import Path

import projsynth

PROBE = """
import os, sys, typer
from projsynth.utils.console import run_console
app = typer.Typer()
@app.command()
def show() -> None:
    print(os.environ.get("OMP_WAIT_POLICY"), "torch" in sys.modules)
run_console(app, "probe")
"""


def _policy(env: dict) -> str:
    env = {**env, "PYTHONPATH": str(Path(projsynth.__file__).parents[1])}
    run = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    return run.stdout.strip()


def test_openmp_threads_sleep_when_idle_unless_the_user_says_otherwise():
    base = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    assert _policy(base) == "PASSIVE False"  # set before torch (and its OpenMP runtime) is loaded
    assert _policy({**base, "OMP_WAIT_POLICY": "ACTIVE"}) == "ACTIVE False"
