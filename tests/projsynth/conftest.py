"""Shared fixtures for the ``projsynth`` end-to-end tests: CLI helpers and two tiny datasets.

Helpers reach the tests through the ``cli`` fixture (``cli.run(...)``, ``cli.PLANAR``), so no test
imports this module. The session datasets are read-only; a test that modifies a dataset copies it
first (``copy_dataset``).
"""

import json
import re
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from projsynth.cli import app


class Cli:
    """What the tests share: the reference option sets and helpers to run ``projsynth`` and read results."""

    # 40 samples of one pair, planar family only: 5 shards of 8 (the determinism/resume reference).
    PLANAR = ["--pairs", "1", "--size", "64x96", "--seed", "11", "--transforms", "0-19"]
    # 16 samples, one transform of each of the 8 families, physical blend: 4 shards of 5, 5, 5, 1.
    MIXED = (
        "--pairs 1 --size 48x64 --seed 3 --transforms 0,37,45,77,85,117,125,157 --blend physical --shard-size 5"
    ).split()
    MIXED_FAMILIES = "planar lens cylinder_convex cylinder_concave sphere_convex sphere_concave wave bumps".split()
    ERROR_PREFIX = "projsynth: error: "
    _SUMMARY = re.compile(r"(\d+) shards written, (\d+) already done, (\d+) in the plan")

    @staticmethod
    def exe() -> str:
        """The installed console script next to this interpreter (for tests that need a real process)."""
        exe = Path(sys.executable).with_name("projsynth")
        found = exe if exe.exists() else shutil.which("projsynth")
        if found is None:
            pytest.skip("the projsynth console script is not installed")
        return str(found)

    @staticmethod
    def run(*args: str | Path) -> Result:
        """Invoke ``projsynth ARGS`` in-process; stdout and stderr are kept apart."""
        return CliRunner().invoke(app, [str(a) for a in args])

    @staticmethod
    def visible_lines(text: str) -> list[str]:
        """Non-empty lines as a terminal shows them: a bar redrawn with ``\\r`` keeps its last state."""
        return [s for s in (line.rsplit("\r", 1)[-1].strip() for line in text.split("\n")) if s]

    @classmethod
    def assert_one_line_error(cls, result: Result, *needles: str | Path) -> str:
        """Exit 2, no traceback, one visible stderr line ``projsynth: error: ...`` containing ``needles``."""
        assert result.exit_code == 2, (result.exit_code, result.stderr, result.exception)
        lines = cls.visible_lines(result.stderr)
        assert len(lines) == 1, lines
        assert lines[0].startswith(cls.ERROR_PREFIX), lines
        assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
        for needle in needles:
            assert str(needle) in lines[0], (needle, lines[0])
        return lines[0]

    @classmethod
    def summary(cls, result: Result) -> tuple[int, int, int]:
        """``(written, already done, in the plan)`` from the line ``gen`` prints without ``--quiet``."""
        m = cls._SUMMARY.search(result.stderr)
        assert m, result.stderr
        return int(m[1]), int(m[2]), int(m[3])

    @staticmethod
    def manifest(root: Path) -> dict:
        return json.loads((Path(root) / "manifest.json").read_text())

    @staticmethod
    def shard_mtimes(root: Path) -> dict[str, int]:
        return {p.name: p.stat().st_mtime_ns for p in sorted(Path(root).glob("shard-*.h5"))}


@pytest.fixture(scope="session")
def cli() -> type[Cli]:
    return Cli


@pytest.fixture(scope="session")
def planar_ds(tmp_path_factory) -> Path:
    """``gen Cli.PLANAR --shard-size 8 --workers 2`` (read-only)."""
    out = tmp_path_factory.mktemp("planar") / "ds"
    result = Cli.run("gen", "--out", out, *Cli.PLANAR, "--shard-size", "8", "--workers", "2", "-q")
    assert result.exit_code == 0, (result.stderr, result.exception)
    return out


@pytest.fixture(scope="session")
def mixed_ds(tmp_path_factory) -> Path:
    """``gen Cli.MIXED`` (read-only)."""
    out = tmp_path_factory.mktemp("mixed") / "ds"
    result = Cli.run("gen", "--out", out, *Cli.MIXED, "-q")
    assert result.exit_code == 0, (result.stderr, result.exception)
    return out


@pytest.fixture(scope="session")
def builtin_toml(tmp_path_factory) -> Path:
    """``projsynth transforms --toml`` saved to a file."""
    result = Cli.run("transforms", "--toml")
    assert result.exit_code == 0, result.stderr
    path = tmp_path_factory.mktemp("table") / "builtin.toml"
    path.write_text(result.stdout)
    return path


@pytest.fixture
def copy_dataset(tmp_path) -> Callable[[Path], Path]:
    """``copy_dataset(src)`` -> a private copy under ``tmp_path`` that the test may modify."""

    def copy(src: Path) -> Path:
        dst = tmp_path / f"copy-{src.parent.name}"
        shutil.copytree(src, dst)
        return dst

    return copy
