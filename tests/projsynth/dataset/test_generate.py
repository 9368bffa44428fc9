"""``projsynth gen`` end to end: determinism, resuming after kill -9, job-array subsets, a full disk."""

import errno
import os
import signal
import subprocess
import time
import zlib
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from projsynth import ProjsynthError
from projsynth.dataset import shards
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import parse_size, resolve_plan
from projsynth.dataset.shards import ShardReader, shard_is_complete
from projsynth.dataset.verify import verify

# --- determinism ------------------------------------------------------------------------------------


def test_samples_do_not_depend_on_workers_or_shard_size(cli, planar_ds, tmp_path):
    other = tmp_path / "w1-s13"
    result = cli.run("gen", "--out", other, *cli.PLANAR, "--shard-size", "13", "--workers", "1", "-q")
    assert result.exit_code == 0, result.stderr

    a, b = cli.manifest(planar_ds), cli.manifest(other)
    assert (a["shard_size"], len(a["shards"])) == (8, 5)
    assert (b["shard_size"], len(b["shards"])) == (13, 4)
    assert [s["count"] for s in b["shards"]] == [13, 13, 13, 1]
    assert a["num_samples"] == b["num_samples"] == 40
    assert a["config_hash"] == b["config_hash"]  # the shard size is not part of the samples' config
    assert a["samples"] == b["samples"]
    assert len({s["sha256"] for s in a["samples"]}) == 40  # every sample differs from every other
    import numba

    assert a["libraries"] == b["libraries"] and len(a["libraries"]) == 1  # the builds that wrote the bytes
    assert (a["libraries"][0]["numpy"], a["libraries"][0]["opencv"], a["libraries"][0]["numba"]) == (
        np.__version__,
        cv2.__version__,
        numba.__version__,
    )

    ra, rb = ShardReader(planar_ds), ShardReader(other)
    try:
        for k in (0, 7, 8, 13, 26, 39):  # on both sides of shard boundaries of either layout
            x, y = ra.read(k), rb.read(k)
            for key in ("projected", "captured", "valid"):
                np.testing.assert_array_equal(x[key], y[key], err_msg=f"{key} of sample {k}")
            assert x["flow"].dtype == y["flow"].dtype == np.float32
            np.testing.assert_array_equal(x["flow"].view(np.uint32), y["flow"].view(np.uint32))
            assert x["params"] == y["params"]
            assert x["params"]["sample_id"] == a["samples"][k]["id"]
    finally:
        ra.close()
        rb.close()

    for root in (planar_ds, other):
        result = cli.run("verify", root)
        assert result.exit_code == 0, result.stderr
        assert cli.visible_lines(result.stderr)[-1] == f"{root}: OK"


def test_seed_changes_every_sample(cli, planar_ds, tmp_path):
    out = tmp_path / "seed12"
    args = [a if a != "11" else "12" for a in cli.PLANAR]
    assert "12" in args
    assert cli.run("gen", "--out", out, *args, "--shard-size", "8", "-q").exit_code == 0
    a, b = cli.manifest(planar_ds)["samples"], cli.manifest(out)["samples"]
    assert [s["id"] for s in a] == [s["id"] for s in b]  # ids are (pair, role, transform) only
    assert all(x["sha256"] != y["sha256"] for x, y in zip(a, b, strict=True))
    ra, rb = ShardReader(planar_ds), ShardReader(out)
    try:  # the source images themselves come from the seed
        assert not np.array_equal(ra.read(0)["projected"], rb.read(0)["projected"])
    finally:
        ra.close()
        rb.close()


# --- interruption and resuming ----------------------------------------------------------------------

KILL_SIZE = (160, 224)
KILL_ARGS = ["--size", "160x224", "--pairs", "1", "--shard-size", "4", "--transforms", "0-39"]  # 20 shards


def _only_complete_shards(root: Path) -> list[str]:
    """Assert every ``shard-*.h5`` opens and is finished; only ``*.tmp`` may be partial. Returns their names."""
    names = []
    for p in sorted(root.iterdir()):
        if p.name.endswith(".tmp"):
            continue
        assert p.name in ("dataset.json", ".gen.lock") or (p.name.startswith("shard-") and p.suffix == ".h5"), p.name
        if p.suffix != ".h5":
            continue
        with h5py.File(p, "r") as f:  # raises if the file is partial
            assert bool(f.attrs["complete"]) and int(f.attrs["count"]) == 4
            assert f["projected"].shape == (4, *KILL_SIZE, 3) and len(f["sample_hash"]) == 4
        names.append(p.name)
    return names


def test_kill_9_then_resume_gives_the_uninterrupted_dataset(cli, tmp_path):
    out = tmp_path / "killed"
    cmd = [cli.exe(), "gen", "--out", str(out), *KILL_ARGS, "-q"]
    with open(tmp_path / "stderr.txt", "wb") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        try:
            deadline = time.monotonic() + 120
            while proc.poll() is None and not any(out.glob("shard-*.h5")) and time.monotonic() < deadline:
                time.sleep(0.002)
            assert proc.poll() is None, "gen finished before it could be killed; enlarge KILL_ARGS"
            os.kill(proc.pid, signal.SIGKILL)
        finally:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL

    assert not (out / "manifest.json").exists()
    done = _only_complete_shards(out)
    assert 1 <= len(done) < 20
    before = cli.shard_mtimes(out)

    result = cli.run("gen", "--out", out, *KILL_ARGS)  # the same command, resumed
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (20 - len(done), len(done), 20)
    after = cli.shard_mtimes(out)
    assert {k: after[k] for k in before} == before  # finished shards were skipped, not rewritten
    assert len(after) == 20 and not list(out.glob("*.tmp"))
    assert verify(out) == []

    ref = tmp_path / "uninterrupted"
    assert cli.run("gen", "--out", ref, *KILL_ARGS, "-q").exit_code == 0
    a, b = cli.manifest(out), cli.manifest(ref)
    assert a["samples"] == b["samples"]
    # the contract is content (per-sample hashes); HDF5's global heap may differ in unused bytes
    layout = [[(s["first_sample"], s["count"]) for s in m["shards"]] for m in (a, b)]
    assert layout[0] == layout[1]


def test_rerunning_a_finished_command_writes_nothing(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    before, manifest = cli.shard_mtimes(root), cli.manifest(root)
    time.sleep(0.01)
    result = cli.run("gen", "--out", root, *cli.PLANAR, "--shard-size", "8", "--workers", "2")
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (0, 5, 5)
    assert "complete, manifest written" in result.stderr
    assert cli.shard_mtimes(root) == before
    assert cli.manifest(root) == manifest


def test_leftover_tmp_files_are_removed_on_resume(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    (root / "shard-00003.h5").unlink()
    (root / "shard-00003.h5.tmp").write_bytes(b"\x89HDF partial")
    result = cli.run("gen", "--out", root, *cli.PLANAR, "--shard-size", "8")
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (1, 4, 5)
    assert not list(root.glob("*.tmp"))
    assert cli.manifest(root)["samples"] == cli.manifest(planar_ds)["samples"]


# --- job arrays: --shards A-B -----------------------------------------------------------------------


def test_shard_subsets_assemble_the_one_shot_dataset(cli, planar_ds, tmp_path):
    out = tmp_path / "array"
    opts = [*cli.PLANAR, "--shard-size", "8"]

    result = cli.run("gen", "--out", out, *opts, "--shards", "0-1")
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (2, 0, 5) and "manifest pending" in result.stderr
    assert sorted(cli.shard_mtimes(out)) == ["shard-00000.h5", "shard-00001.h5"]
    assert not (out / "manifest.json").exists()
    cli.assert_one_line_error(cli.run("merge", out), "3 of 5", "shard-00002.h5")

    result = cli.run("gen", "--out", out, *opts, "--shards", "4")  # a single index
    assert result.exit_code == 0 and cli.summary(result) == (1, 0, 5)
    assert not (out / "manifest.json").exists()
    cli.assert_one_line_error(cli.run("merge", out), "2 of 5", "shard-00002.h5")

    result = cli.run("gen", "--out", out, *opts, "--shards", "2-3")
    assert result.exit_code == 0 and cli.summary(result) == (2, 0, 5)
    assert "complete, manifest written" in result.stderr
    one_shot, assembled = cli.manifest(planar_ds), cli.manifest(out)
    assert assembled["samples"] == one_shot["samples"]
    assert [s["count"] for s in assembled["shards"]] == [s["count"] for s in one_shot["shards"]]

    (out / "manifest.json").unlink()
    result = cli.run("merge", out)
    assert result.exit_code == 0, result.stderr
    assert "manifest of 40 samples in 5 shards" in result.stderr
    assert cli.manifest(out) == assembled
    assert cli.run("verify", out, "-q").exit_code == 0


def test_merge_of_a_directory_without_a_plan(cli, tmp_path):
    cli.assert_one_line_error(cli.run("merge", tmp_path), tmp_path / "dataset.json")


# --- full disk --------------------------------------------------------------------------------------


def _enospc(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _fail_at_open(monkeypatch):
    real = open

    def fake_open(name, mode="r", *args, **kwargs):
        if str(name).endswith(".h5.tmp"):
            _enospc()
        return real(name, mode, *args, **kwargs)

    monkeypatch.setattr(shards, "open", fake_open, raising=False)


def _fail_mid_write(monkeypatch):
    """Half the shard's bytes reach the .tmp file, then the disk is full."""
    real = open

    class HalfWriter:
        def __init__(self, fh):
            self.fh = fh

        def write(self, data):
            self.fh.write(data[: len(data) // 2])
            self.fh.flush()
            _enospc()

        def __getattr__(self, name):
            return getattr(self.fh, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    def fake_open(name, mode="r", *args, **kwargs):
        fh = real(name, mode, *args, **kwargs)
        return HalfWriter(fh) if str(name).endswith(".h5.tmp") else fh

    monkeypatch.setattr(shards, "open", fake_open, raising=False)


def _fail_at_rename(monkeypatch):
    real = os.replace

    def replace(src, dst, *args, **kwargs):  # the .tmp file is complete and fsynced
        if str(src).endswith(".h5.tmp"):
            assert Path(src).stat().st_size > 0
            _enospc()
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(shards.os, "replace", replace)


@pytest.mark.parametrize("inject", [_fail_at_open, _fail_mid_write, _fail_at_rename])
def test_full_disk_leaves_no_shard_and_resumes(inject, monkeypatch, tmp_path):
    plan = resolve_plan(size=parse_size("48x64"), seed=0, split="train", pairs=1, transforms="0-3", blend="paper")
    out = tmp_path / "ds"
    with monkeypatch.context() as m:
        inject(m)
        with pytest.raises(ProjsynthError) as info:
            generate(plan, out, shard_size=2, workers=1)
    message = str(info.value)
    assert "no space left" in message and "shard-00000.h5" in message and "\n" not in message
    assert sorted(p.name for p in out.iterdir()) == [".gen.lock", "dataset.json"]  # no shard, no .tmp

    result = generate(plan, out, shard_size=2, workers=1)  # space freed: the same call resumes
    assert (result.written, result.skipped, result.num_shards) == ([0, 1, 2, 3], [], 4)
    assert result.manifest is not None and result.manifest["num_samples"] == 8
    assert all(shard_is_complete(out / shards.shard_name(j), result.manifest["config_hash"]) for j in range(4))
    assert verify(out) == []


# --- image folders ----------------------------------------------------------------------------------


def test_gen_from_image_folders_is_deterministic(cli, tmp_path):
    rng = np.random.default_rng(0)
    for kind in ("nat", "gen"):
        folder = tmp_path / kind / ("Forest" if kind == "nat" else "")  # natural: scene label from the subfolder
        folder.mkdir(parents=True)
        for i in range(12):
            cv2.imwrite(str(folder / f"{kind}{i}.png"), rng.integers(0, 256, (60, 80, 3), np.uint8))
    opts = ["--natural", tmp_path / "nat", "--generated", tmp_path / "gen"]
    opts += "--pairs 1 --size 48x64 --transforms 0-1 -q".split()
    for name in ("a", "b"):
        result = cli.run("gen", "--out", tmp_path / name, *opts, "--shard-size", "3" if name == "a" else "4")
        assert result.exit_code == 0, (result.stderr, result.exception)
    a, b = cli.manifest(tmp_path / "a"), cli.manifest(tmp_path / "b")
    assert a["num_samples"] == 4 and a["samples"] == b["samples"]
    names = a["sources"]
    assert len(names["natural"]) == len(names["generated"]) == 1
    assert names["natural"][0].startswith("Forest/nat") and names["generated"][0].startswith("gen")
    assert cli.run("verify", tmp_path / "a", "-q").exit_code == 0
    reader = ShardReader(tmp_path / "a")
    try:  # role 0 projects the natural image, role 1 the generated one, each fitted to 48x64
        r0, r1 = reader.read(0), reader.read(2)
        assert r0["params"]["sources"]["projected"] == names["natural"][0]
        assert r1["params"]["sources"]["projected"] == names["generated"][0]
        assert (r0["params"]["sources"]["projected_theme"], r0["params"]["sources"]["background_theme"]) == (
            "forest",
            None,
        )
        assert (r1["params"]["sources"]["projected_theme"], r1["params"]["sources"]["background_theme"]) == (
            None,
            "forest",
        )
        assert r0["projected"].shape == (48, 64, 3) and not np.array_equal(r0["projected"], r1["projected"])
    finally:
        reader.close()


def _read_in_child(reader, k, queue):
    queue.put(reader.read(k, with_params=False)["flow"].sum())


def test_reader_decodes_on_a_thread_names_a_bad_flow_and_survives_a_fork(planar_ds, tmp_path):
    import multiprocessing as mp
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(planar_ds, copy)
    bad = b"not an exr file" * 10
    with h5py.File(copy / "shard-00000.h5", "r+") as f:
        f["flow_exr"][1] = np.frombuffer(bad, np.uint8)
        f["crc32"][1, 0] = zlib.crc32(bad)  # past the checksum: the decoder is the one to notice
    reader = ShardReader(copy)
    try:
        first = reader.read(0)
        with pytest.raises(ProjsynthError, match=r"shard-00000\.h5: sample 1 unreadable \(not a valid OpenEXR"):
            reader.read(1)
        np.testing.assert_array_equal(reader.read(0)["flow"], first["flow"])  # a failed decode leaves no trace
        queue = mp.get_context("fork").Queue()
        child = mp.get_context("fork").Process(target=_read_in_child, args=(reader, 0, queue), daemon=True)
        child.start()
        try:
            assert queue.get(timeout=60) == first["flow"].sum()  # the child reads (and decodes) too
        finally:
            child.join(timeout=10)
            child.kill()
    finally:
        reader.close()


def test_reader_keeps_at_most_max_open_files(planar_ds):
    """A pass over a dataset of any size stays within the file-descriptor limit (5 shards, 2 open)."""
    small, full = ShardReader(planar_ds, max_open=2), ShardReader(planar_ds)
    try:
        order = [*range(40), *np.random.default_rng(0).permutation(40).tolist()]
        for k in order:
            np.testing.assert_array_equal(small.read(k)["captured"], full.read(k)["captured"])
            assert len(small._files) <= 2 and all(f.id.valid for f in small._files.values())
        assert len(full._files) == 5
        assert next(reversed(small._files)) == order[-1] // 8  # the last one read is kept
    finally:
        small.close()
        full.close()


@pytest.mark.parametrize("shards,tasks", [(7, 3), (4, 6), (64, 16), (1, 1)])
def test_array_task_shares_cover_the_plan_once_and_differ_by_at_most_one(shards, tasks):
    from projsynth.dataset.generate import parse_shard_range

    shares = [list(parse_shard_range(f"{k}/{tasks}", shards)) for k in range(tasks)]
    assert [j for share in shares for j in share] == list(range(shards))
    assert max(map(len, shares)) - min(map(len, shares)) <= 1


@pytest.mark.parametrize("spec", ["3/3", "-1/3", "a/3", "1/0", "1/2/3"])
def test_bad_array_task_specs_are_one_line_errors(spec):
    from projsynth.dataset.generate import parse_shard_range

    with pytest.raises(ProjsynthError, match="--shards"):
        parse_shard_range(spec, 8)


def test_progress_is_per_sample_from_worker_processes(tmp_path):
    """Two workers, two shards of 4: the bar hears of every sample as it is rendered, not per shard."""
    plan = resolve_plan(size=(48, 64), seed=1, split="train", pairs=1, transforms="0-3", blend="paper")
    ticks, totals = [], []
    generate(plan, tmp_path / "ds", shard_size=4, workers=2, progress=ticks.append, progress_total=totals.append)
    assert totals == [8] and ticks == [0] + [1] * 8
    ticks.clear()
    generate(plan, tmp_path / "ds", shard_size=4, workers=2, progress=ticks.append)  # all done: one call
    assert ticks == [8]


def test_a_first_run_says_that_it_compiles_the_kernels(monkeypatch):
    """A cold cache (every kernel missing): one line before the compilation and one after it; a warm
    cache, or a kernel or two that earlier plans did not need, says nothing."""
    import projsynth.dataset.generate as gen
    from projsynth.utils.jit import KERNELS

    plan = resolve_plan(size=(48, 64), seed=1, split="train", pairs=1, transforms="0,45", blend="paper")
    for missing, expected in ((len(KERNELS), 2), (1, 0), (0, 0)):
        lines = []
        monkeypatch.setattr(gen, "uncompiled_kernels", lambda n=missing: ["kernel"] * n)
        gen.compile_kernels(plan, lines.append)
        assert len(lines) == expected, lines
        if expected:
            assert lines[0] == f"compiling kernels (first run, ~{gen.COMPILE_SECONDS} s)..."
            assert lines[1].startswith("kernels compiled in ")


# --- sequences ----------------------------------------------------------------------------------------

SEQUENCE = "--pairs 1 --size 48x64 --seed 4 --transforms 0,125 --frames 3 --motion gust".split()


def test_sequences_do_not_depend_on_workers_or_shard_size_and_resume_refuses_other_frames(cli, tmp_path):
    a, b = tmp_path / "w2-s3", tmp_path / "w1-s6"
    result = cli.run("gen", "--out", a, *SEQUENCE, "--shard-size", "3", "--workers", "2", "-q")
    assert result.exit_code == 0, result.stderr
    result = cli.run("gen", "--out", b, *SEQUENCE, "--workers", "1", "-q")  # default: 63, whole sequences
    assert result.exit_code == 0, result.stderr
    ma, mb = cli.manifest(a), cli.manifest(b)
    assert (ma["frames"], ma["motion"], ma["num_samples"], len(ma["shards"])) == (3, "gust", 12, 4)
    assert (mb["shard_size"], len(mb["shards"])) == (63, 1)
    assert ma["samples"] == mb["samples"] and ma["config_hash"] == mb["config_hash"]
    assert [s["id"] for s in ma["samples"][:4]] == [
        "train-p00000-r0-t000-f000",
        "train-p00000-r0-t000-f001",
        "train-p00000-r0-t000-f002",
        "train-p00000-r0-t125-f000",
    ]
    for root in (a, b):
        assert cli.run("verify", root).exit_code == 0
    # the frames and the motion are part of the plan: resuming with others is refused
    for other in ([], ["--frames", "3", "--motion", "hover"]):
        result = cli.run("gen", "--out", a, *SEQUENCE[:-4], *other, "--shard-size", "3", "-q")
        cli.assert_one_line_error(result, "other options")
    plans = [
        resolve_plan(size=(48, 64), seed=4, split="train", pairs=1, transforms="0,125", blend="paper", **kw)
        for kw in ({}, {"frames": 3, "motion": "gust"}, {"frames": 4, "motion": "gust"})
    ]
    assert len({p.config_hash() for p in plans}) == 3
    assert plans[1].config_hash() == ma["config_hash"]
    assert "frames" not in plans[0].describe()  # single-frame plans hash as before sequences existed
    # an edited manifest shows: other frames break the arithmetic, another motion the hash
    from projsynth.dataset.manifest import manifest_problems

    assert manifest_problems(ma, a / "manifest.json") == []
    frames = manifest_problems({**ma, "frames": 6}, a / "manifest.json")
    assert any("not whole sequences" in p for p in frames) and any("x frames) makes 24" in p for p in frames)
    assert "does not hash" in manifest_problems({**ma, "motion": "orbit"}, a / "manifest.json")[0]
    assert "frames is 1" in manifest_problems({**ma, "frames": 1}, a / "manifest.json")[0]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--frames", "3", "--shard-size", "4"], "--shard-size"),
        (["--motion", "gust"], "--motion"),
        (["--frames", "3", "--motion", "wobble"], "--motion"),
        (["--frames", "0"], "--frames"),
    ],
)
def test_bad_sequence_options_are_one_line_errors(cli, tmp_path, args, needle):
    result = cli.run("gen", "--out", tmp_path / "x", "--pairs", "1", "--size", "48x64", "--transforms", "0", *args)
    cli.assert_one_line_error(result, needle)
