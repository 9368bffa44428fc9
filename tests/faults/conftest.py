"""The bad-input and fault probe of issue 17, kept as a test corpus: dataset ``D`` and the checks every case
shares (exit 2 and one ``PROG: error:`` line for bad input; nothing written; no input overwritten).

``D`` is ``projsynth gen --out D --pairs 1 --size 96x128 --transforms 0-15 --shard-size 8 --quiet``:
32 samples in 4 shards. The session copy is read-only; a case that damages it works on ``d_copy``.
"""

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import h5py
import pytest
from typer.testing import CliRunner, Result

import projsynth
from projreg.cli import app as projreg_app
from projsynth.cli import app as projsynth_app

D_ARGS = ["--pairs", "1", "--size", "96x128", "--transforms", "0-15", "--shard-size", "8", "--quiet"]


@dataclass(frozen=True)
class Ran:
    """How a process ended, as the checks read a CliRunner result."""

    exit_code: int
    stdout: str
    stderr: str
    exception: None = None


class Probe:
    """Run either command line in-process, and check how a case ended."""

    D_ARGS = D_ARGS

    @staticmethod
    def projsynth(*args: str | Path) -> Result:
        return CliRunner().invoke(projsynth_app, [str(a) for a in args])

    @staticmethod
    def projreg(*args: str | Path) -> Result:
        return CliRunner().invoke(projreg_app, [str(a) for a in args])

    @staticmethod
    def process(prog: str, *args: str | Path, cwd: Path | None = None, preexec_fn=None) -> "Ran":
        """Run ``PROG ARGS`` as its console command does, in a new process (usage errors are formatted
        there; a crash shows as a signal), with this checkout's packages."""
        env = {**os.environ, "PYTHONPATH": str(Path(projsynth.__file__).parents[1])}
        run = subprocess.run(
            [sys.executable, "-m", f"{prog}.cli", *map(str, args)],
            cwd=cwd,
            env=env,
            preexec_fn=preexec_fn,
            capture_output=True,
            text=True,
            timeout=600,
        )
        return Ran(run.returncode, run.stdout, run.stderr)

    @staticmethod
    def error(result: Result | Ran, *needles: str | Path, code: int = 2) -> str:
        """``result`` ended with ``code`` and one stderr line ``projsynth: error:`` or ``projreg: error:``
        (``verify: `` lines for code 1) holding every needle, and no traceback; returns the line."""
        assert result.exit_code == code, (result.exit_code, result.stderr, result.exception)
        lines = [s for s in (line.rsplit("\r", 1)[-1].strip() for line in result.stderr.split("\n")) if s]
        assert len(lines) == 1 or code == 1, lines
        assert all(s.split(": ")[0] in ("projsynth", "projreg") for s in lines), lines
        assert "Traceback" not in result.stderr + result.stdout
        for needle in needles:
            assert any(str(needle) in s for s in lines), (needle, lines)
        return lines[0]

    @staticmethod
    def flip_chunks(shard: Path, dataset: str = "captured") -> None:
        """Flip one byte in the middle of every stored chunk of ``dataset`` (one chunk per sample)."""
        with h5py.File(shard, "r") as f:
            d = f[dataset]
            spots = [d.id.get_chunk_info(i) for i in range(d.id.get_num_chunks())]
        data = bytearray(shard.read_bytes())
        for c in spots:
            data[c.byte_offset + c.size // 2] ^= 0x20
        shard.write_bytes(bytes(data))


@pytest.fixture(scope="session")
def probe() -> type[Probe]:
    return Probe


@pytest.fixture(scope="session")
def dataset_d(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("faults") / "D"
    result = Probe.projsynth("gen", "--out", out, *D_ARGS)
    assert result.exit_code == 0, (result.stderr, result.exception)
    return out


@pytest.fixture
def d_copy(dataset_d, tmp_path) -> Path:
    """A private copy of ``D`` the case may damage."""
    return Path(shutil.copytree(dataset_d, tmp_path / "D"))
