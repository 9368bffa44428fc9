"""Defect 1: damaged or foreign shards are refused by every reader, not only by ``verify``."""

import shutil

import h5py
import pytest

import projreg.evaluation.methods
from projsynth.dataset.shards import shard_name

READERS = ["inspect", "export", "preview", "train", "bench"]


def _read_with(probe, command, root, tmp_path):
    args = {
        "inspect": ["inspect", root],
        "export": ["export", root, "--out", tmp_path / "x", "-q"],
        "preview": ["preview", root, "--out", tmp_path / "p.png"],
    }
    if command in args:
        return probe.projsynth(*args[command])
    if command == "train":
        options = "--steps 1 --batch-size 2 --crop none --workers 0 -q".split()
        return probe.projreg("train", "--data", root, "--out", tmp_path / "run", *options)
    return probe.projreg("bench", "--data", root, "--baselines", "farneback", "-q")


@pytest.fixture
def no_reference(monkeypatch):
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)


@pytest.mark.parametrize("command", READERS)
def test_a_flipped_byte_in_a_captured_image_is_refused(probe, d_copy, tmp_path, no_reference, command):
    for j in range(4):
        probe.flip_chunks(d_copy / shard_name(j), "captured")
    line = probe.error(_read_with(probe, command, d_copy, tmp_path), "shard-0000", "projsynth verify")
    assert "fails its Fletcher-32 checksum" in line, line
    assert not (tmp_path / "p.png").exists() and not (tmp_path / "run").exists()


@pytest.mark.parametrize("command", READERS)
def test_a_shard_copied_in_from_another_dataset_is_refused(probe, d_copy, tmp_path, no_reference, command):
    other = tmp_path / "other"
    assert probe.projsynth("gen", "--out", other, *probe.D_ARGS, "--seed", "1").exit_code == 0
    for j in range(4):
        shutil.copyfile(other / shard_name(j), d_copy / shard_name(j))
    probe.error(_read_with(probe, command, d_copy, tmp_path), "not this dataset's shard", "projsynth verify")


def test_a_shard_copied_to_another_place_of_its_own_dataset_is_refused(probe, d_copy, tmp_path):
    """Same config hash, wrong place: the first sample gives it away."""
    shutil.copyfile(d_copy / shard_name(0), d_copy / shard_name(1))
    probe.error(probe.projsynth("inspect", d_copy), shard_name(1), "not this dataset's shard 1")
    probe.error(probe.projsynth("verify", d_copy, "-q"), shard_name(1), code=1)


@pytest.mark.parametrize(("column", "i"), [("flow_exr", 3), ("params", 5)])
def test_a_damaged_flow_or_parameter_record_fails_its_crc(probe, d_copy, column, i):
    """The variable-length datasets (HDF5 cannot checksum them) are covered by the ``crc32`` dataset."""
    with h5py.File(d_copy / shard_name(2), "r+") as f:
        if column == "flow_exr":
            exr = f["flow_exr"][i].copy()
            exr[len(exr) // 2] ^= 1
            f["flow_exr"][i] = exr
        else:
            f["params"][i] = f["params"][i].replace(b'"pair": 0', b'"pair": 1')
    probe.error(probe.projsynth("inspect", d_copy), shard_name(2), f"sample {i}", f"{column} fails its CRC-32")
