"""Defects 2, 3, 4, 5, 12 and 14: `projsynth gen` on a full disk, bad options, odd source files, a second
`gen` on the same directory, and malformed transform tables."""

import multiprocessing as mp
import os
import resource
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest

from projsynth.dataset.transforms import builtin_table


def _limit_file_size() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead of killing
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


@pytest.mark.parametrize("shard_size", ["2", "8"])
def test_a_full_disk_is_one_line_not_a_crash(probe, tmp_path, shard_size):
    """A file-size limit stands in for a full tmpfs (mounting one needs root): the shard's write fails
    in the same way, ``errno`` EFBIG instead of ENOSPC. Before the fix: exit 139 (SIGSEGV)."""
    out = tmp_path / "ds"
    args = [a if a != "8" else shard_size for a in probe.D_ARGS]
    result = probe.process("projsynth", "gen", "--out", out, *args, preexec_fn=_limit_file_size)
    probe.error(result, "shard-00000.h5: cannot write shard (file too large")
    assert not list(out.glob("shard-*"))  # no shard, no .tmp


@pytest.mark.parametrize("seed", [str(2**64), "-1"])
def test_a_seed_outside_64_bits_is_refused_up_front(probe, tmp_path, seed):
    out = tmp_path / "ds"
    probe.error(probe.projsynth("gen", "--out", out, *probe.D_ARGS, "--seed", seed), "--seed", str(2**64 - 1))
    assert not out.exists()


def test_the_largest_seed_works(probe, tmp_path):
    out = tmp_path / "ds"
    result = probe.projsynth(
        "gen", "--out", out, "--pairs", "1", "--size", "32x32", "--transforms", "0", "--seed", str(2**64 - 1), "-q"
    )
    assert result.exit_code == 0, result.stderr
    assert probe.projsynth("verify", out, "-q").exit_code == 0


@pytest.mark.parametrize("command", ["gen", "export"])
def test_an_empty_out_is_refused(probe, tmp_path, dataset_d, command):
    args = ["gen", "--out", "", *probe.D_ARGS] if command == "gen" else ["export", dataset_d, "--out", ""]
    probe.error(probe.process("projsynth", *args, cwd=tmp_path), "--out", "empty")
    assert list(tmp_path.iterdir()) == []


def test_a_fifo_among_the_sources_is_skipped_not_waited_for(probe, tmp_path):
    for kind in ("natural", "generated"):
        (tmp_path / kind).mkdir()
        for i in range(2):
            image = np.random.default_rng(i).integers(0, 255, (48, 48, 3), np.uint8)
            assert cv2.imwrite(str(tmp_path / kind / f"{i}.png"), image)
    os.mkfifo(tmp_path / "natural" / "pipe.png")

    def hung(*_):
        raise TimeoutError("gen waited for a writer of the FIFO")  # as it did before the fix

    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(120)
    try:
        folders = ["--natural", tmp_path / "natural", "--generated", tmp_path / "generated"]
        result = probe.projsynth(
            "gen", "--out", tmp_path / "ds", *folders, *"--split all --pairs 2 --size 32x32 --transforms 0 -q".split()
        )
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert result.exit_code == 0, result.stderr
    assert f"skipped {tmp_path / 'natural' / 'pipe.png'}: cannot read image (not a regular file)" in result.stderr


def _hold(out: Path, shards: range, ready, release) -> None:
    from projsynth.dataset.generate import claim_shards

    with claim_shards(out, shards):
        ready.set()
        release.wait(60)


def test_a_second_gen_on_the_same_shards_says_another_gen_is_writing(probe, tmp_path):
    out = tmp_path / "ds"
    assert probe.projsynth("gen", "--out", out, *probe.D_ARGS, "--shards", "3").exit_code == 0  # the plan exists
    ctx = mp.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    other = ctx.Process(target=_hold, args=(out, range(0, 2), ready, release))  # another gen, at shards 0-1
    other.start()
    try:
        assert ready.wait(60)
        line = probe.error(probe.projsynth("gen", "--out", out, *probe.D_ARGS), "another `projsynth gen` is writing")
        assert str(out) in line
        assert sorted(p.name for p in out.glob("shard-*")) == ["shard-00003.h5"]  # nothing touched
        # a job array's disjoint range runs beside it
        assert probe.projsynth("gen", "--out", out, *probe.D_ARGS, "--shards", "2").exit_code == 0
    finally:
        release.set()
        other.join(60)
    assert probe.projsynth("gen", "--out", out, *probe.D_ARGS).exit_code == 0  # released: it resumes


def _row(**changes: str) -> str:
    """One [[transform]] entry (the built-in row 0), with fields replaced by TOML text."""
    c = builtin_table().configs[0]

    def inline(ranges):
        return "{" + ", ".join(f"{k} = [{a!r}, {b!r}]" for k, (a, b) in ranges.items()) + "}"

    row = {
        "id": "0",
        "name": '"t0"',
        "family": '"planar"',
        "severity": "1",
        "condition": '"studio"',
        "geometry": inline(c.geometry),
        "photometry": inline(c.photometry),
    }
    row.update(changes)
    return "[[transform]]\n" + "\n".join(f"{k} = {v}" for k, v in row.items() if v is not None) + "\n"


BAD_TABLES = {
    "geometry an integer": (_row(geometry="5"), "geometry must be a table"),
    "photometry a string": (_row(photometry='"dim"'), "photometry must be a table"),
    "id a string": (_row(id='"0"'), "id must be an integer"),
    "id a boolean": (_row(id="true"), "id must be an integer"),
    "family a number": (_row(family="3"), "family must be a string"),
    "name a number": (_row(name="7"), "name must be a string"),
    "severity a string": (_row(severity='"high"'), "severity must be an integer"),
    "no geometry": (_row(geometry=None), "missing key(s) geometry"),
    "a range of strings": (_row(geometry='{fov_deg = ["a", "b"]}'), "fov_deg must be a [low, high] pair"),
    "a range that is a number": (_row(geometry="{fov_deg = 5}"), "fov_deg must be a [low, high] pair"),
    "a range of booleans": (_row(geometry="{fov_deg = [true, true]}"), "fov_deg must be a [low, high] pair"),
    "entries that are numbers": ("transform = [1, 2]\n", "expected a [[transform]] table"),
}


@pytest.mark.parametrize("case", BAD_TABLES)
def test_a_bad_transform_table_names_the_row_and_field(probe, tmp_path, case):
    text, message = BAD_TABLES[case]
    path = tmp_path / "table.toml"
    path.write_text(text)
    line = probe.error(probe.projsynth("transforms", "--table", path), path, "transform #0", message)
    assert "object has no attribute" not in line and "object is not" not in line
