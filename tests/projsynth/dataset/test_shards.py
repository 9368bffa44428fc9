"""Shard format 2 (checksums) and format 1 (before them), as ``projsynth.dataset.shards`` writes and reads them."""

import json
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from projsynth import FORMAT_VERSION, ProjsynthError
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import make_sample, resolve_plan
from projsynth.dataset.shards import CRC_COLUMNS, ShardReader, shard_name
from projsynth.dataset.verify import inspect, verify

FORMAT1 = Path(__file__).parents[2] / "faults" / "data" / "format1"  # written by projsynth 0.2.0 (commit 242a210)


def test_every_fixed_size_dataset_has_fletcher32_and_the_others_a_crc(planar_ds):
    with h5py.File(planar_ds / shard_name(0), "r") as f:
        assert f.attrs["format_version"] == FORMAT_VERSION == 2
        fixed = [
            name
            for name in f
            if f[name].dtype.kind not in "OV"
            and h5py.check_vlen_dtype(f[name].dtype) is None
            and h5py.check_string_dtype(f[name].dtype) is None
        ]
        assert sorted(fixed) == ["captured", "crc32", "projected", "transform_id", "valid"]
        assert all(f[name].fletcher32 for name in fixed)
        assert sorted(set(f) - set(fixed)) == sorted(CRC_COLUMNS)
        assert f["crc32"].attrs["columns"] == ",".join(CRC_COLUMNS)
        for i in range(int(f.attrs["count"])):
            stored = [f["flow_exr"][i].tobytes(), *(f[name][i] for name in CRC_COLUMNS[1:])]
            assert [zlib.crc32(b) for b in stored] == f["crc32"][i].tolist()


def test_the_copied_projected_chunk_keeps_a_valid_checksum(planar_ds):
    """The samples of a pair and role share one projected frame: its raw chunk (with its Fletcher-32
    checksum) is copied with write_direct_chunk, and every copy reads back, checksum verified."""
    plan = resolve_plan(size=(64, 96), seed=11, split="train", pairs=1, transforms="0-19", blend="paper")
    with h5py.File(planar_ds / shard_name(1), "r") as f:  # samples 8..15: all of role 0, one frame
        d = f["projected"]
        chunks = [d.id.read_direct_chunk((i, 0, 0, 0)) for i in range(8)]
        assert len({c[1] for c in chunks}) == 1 and d.fletcher32
        frame = make_sample(plan, 8).projected
        for i in range(8):
            np.testing.assert_array_equal(d[i], frame)


def test_a_damaged_copied_chunk_is_noticed(planar_ds, tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes((planar_ds / shard_name(1)).read_bytes())
    with h5py.File(path, "r") as f:
        info = f["projected"].id.get_chunk_info(5)
    data = bytearray(path.read_bytes())
    data[info.byte_offset + 7] ^= 0x01
    path.write_bytes(bytes(data))
    with h5py.File(path, "r") as f:
        f["projected"][4]  # the chunk before is intact
        with pytest.raises(OSError, match="filter returned failure"):
            f["projected"][5]


def test_a_format_1_dataset_still_reads():
    """No checksums to check there; everything else as before: reader, inspect and verify."""
    manifest = json.loads((FORMAT1 / "manifest.json").read_text())
    assert manifest["format_version"] == 1
    with h5py.File(FORMAT1 / shard_name(0), "r") as f:
        assert "crc32" not in f and not f["captured"].fletcher32
    reader = ShardReader(FORMAT1)
    try:
        samples = [reader.read(k, flow_exr=True) for k in range(len(reader))]
    finally:
        reader.close()
    assert [s["params"]["sample_id"] for s in samples] == [s["id"] for s in manifest["samples"]]
    assert all(s["projected"].shape == (32, 48, 3) and s["flow"].shape == (32, 48, 2) for s in samples)
    assert verify(FORMAT1) == []
    assert inspect(FORMAT1)["total"]["samples"] == 2


def test_a_format_1_dataset_is_not_resumed_as_format_2(tmp_path):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "dataset.json").write_text((FORMAT1 / "dataset.json").read_text())
    plan = resolve_plan(size=(32, 48), seed=7, split="train", pairs=1, transforms="21", blend="paper")
    with pytest.raises(ProjsynthError, match="holds a format 1 dataset, this projsynth writes format 2"):
        generate(plan, out, shard_size=1)
