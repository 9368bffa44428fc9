"""``projsynth verify``, ``inspect``, ``export`` and ``preview`` on tiny generated datasets."""

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from projsynth.dataset.export import label_height
from projsynth.dataset.plan import Sample
from projsynth.dataset.shards import ShardReader, shard_name
from projsynth.dataset.verify import bucket_of
from projsynth.flow.formats import FLO_UNKNOWN, decode_flow_exr, encode_flow_exr, read_flo
from projsynth.flow.pictures import flow_to_color
from projsynth.utils.files import file_sha256

# --- damaged files ----------------------------------------------------------------------------------


def _flip_middle(path: Path, n: int = 64) -> None:
    data = bytearray(path.read_bytes())
    m = len(data) // 2
    data[m : m + n] = bytes(b ^ 0xFF for b in data[m : m + n])
    path.write_bytes(bytes(data))


def _problems(cli, result) -> list[str]:
    assert result.exit_code == 1, (result.exit_code, result.stderr, result.exception)
    lines = [s for s in cli.visible_lines(result.stderr) if s.startswith("projsynth: ")]
    assert lines and all(s.startswith("projsynth: verify: ") for s in lines), lines
    return lines


def test_intact_dataset_verifies(cli, planar_ds, mixed_ds):
    for root in (planar_ds, mixed_ds):
        result = cli.run("verify", root)
        assert result.exit_code == 0, result.stderr
        assert cli.visible_lines(result.stderr) == [f"{root}: OK"]


@pytest.mark.parametrize("j", [0, 2, 4])
def test_flipped_bytes_name_the_shard(cli, planar_ds, copy_dataset, j):
    root = copy_dataset(planar_ds)
    _flip_middle(root / shard_name(j))
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert f"{root / shard_name(j)}: sha256 differs from the manifest" in lines[0]
    assert all(shard_name(k) not in s for s in lines for k in range(j))  # earlier shards are fine


def test_deleted_shard_is_named(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    (root / "shard-00001.h5").unlink()
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert lines[0].startswith(f"projsynth: verify: {root / 'shard-00001.h5'}: missing")
    assert "--shards 1" in lines[0]


@pytest.mark.parametrize("damage", ["delete shard 1", "flip shard 2"])
def test_verify_names_only_the_damaged_shard(cli, planar_ds, copy_dataset, damage):
    root = copy_dataset(planar_ds)
    j = int(damage[-1])
    if damage.startswith("delete"):
        (root / shard_name(j)).unlink()
    else:
        _flip_middle(root / shard_name(j))
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert all(str(root / shard_name(j)) in s for s in lines), lines


def _drop_last_shard(m: dict) -> None:
    last = m["shards"].pop()
    m["samples"] = m["samples"][: last["first_sample"]]
    m["num_samples"] = len(m["samples"])


MANIFEST_ARITHMETIC = {
    "last shard dropped": (_drop_last_shard, "lists 4 shards, num_shards says 5"),
    "num_samples changed": (lambda m: m.update(num_samples=99), "num_samples is 99 but the shard counts sum to 40"),
    "shards swapped": (lambda m: m["shards"].reverse(), "shard entry 0 is not shard 0 starting at sample 0"),
    "a short middle shard": (lambda m: m["shards"][1].update(count=3), "shard 1 holds 3 samples"),
}


@pytest.mark.parametrize("damage", MANIFEST_ARITHMETIC)
def test_manifest_that_does_not_tile_the_plan_fails_verify(cli, planar_ds, copy_dataset, damage):
    """Every file still hashes as listed: only the manifest's own arithmetic is wrong."""
    root = copy_dataset(planar_ds)
    path = root / "manifest.json"
    manifest = json.loads(path.read_text())
    assert (len(manifest["shards"]), manifest["num_samples"]) == (5, 40)
    edit, message = MANIFEST_ARITHMETIC[damage]
    edit(manifest)
    path.write_text(json.dumps(manifest))
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert any(str(path) in s and message in s for s in lines), lines


@pytest.mark.parametrize(
    ("attr", "value"), [("first_sample", 0), ("count", 7), ("generator", "projsynth 9.9.9"), ("format_version", 1)]
)
def test_shard_attribute_that_disagrees_with_the_manifest_fails_verify(cli, planar_ds, copy_dataset, attr, value):
    root = copy_dataset(planar_ds)
    shard = root / shard_name(1)
    with h5py.File(shard, "r+") as f:
        f.attrs[attr] = value
    path = root / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["shards"][1]["sha256"] = file_sha256(shard)  # the file hash alone would not notice
    path.write_text(json.dumps(manifest))
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert lines == [
        f"projsynth: verify: {shard}: attributes do not match the manifest (config hash, shard index, "
        "first sample, count, format version or generator)"
    ]


MANIFEST_DAMAGE = [
    "truncated",
    "missing",
    "other format",
    "not utf-8",
    "a list",
    "no keys",
]


@pytest.mark.parametrize("damage", MANIFEST_DAMAGE)
def test_bad_manifest_is_one_line_exit_2(cli, planar_ds, copy_dataset, damage):
    root = copy_dataset(planar_ds)
    path = root / "manifest.json"
    text = path.read_text()
    if damage == "missing":
        path.unlink()
    else:
        path.write_bytes(
            {
                "truncated": text[: len(text) // 2].encode(),
                "other format": json.dumps({**json.loads(text), "format_version": 99}).encode(),
                "not utf-8": b"\x00\xff garbage",
                "a list": b"[]",
                "no keys": b'{"format_version": 1}',
            }[damage]
        )
    extra = {"verify": [], "inspect": ["--json"], "preview": ["--out", root / "x.png"], "export": ["--out", root / "x"]}
    for command, options in extra.items():
        cli.assert_one_line_error(cli.run(command, root, *options), path)
    assert not (root / "x.png").exists() and not (root / "x").exists()


def test_inspect_without_the_plan_file(cli, mixed_ds, copy_dataset):
    root = copy_dataset(mixed_ds)
    (root / "dataset.json").unlink()
    result = cli.run("inspect", root, "--json")
    assert result.exit_code == 0 or cli.assert_one_line_error(result, root / "dataset.json")


def test_verify_of_a_missing_directory(cli, tmp_path):
    cli.assert_one_line_error(cli.run("verify", tmp_path / "nope"), tmp_path / "nope" / "manifest.json")


# --- consistent but wrong content: the checks behind the file hash ----------------------------------


def _tamper(root: Path, k: int, edit: Callable[[dict], None], rehash: bool = True) -> str:
    """Apply ``edit`` to sample ``k``'s arrays (projected, captured, valid, flow, exr_valid) and write them
    back; with ``rehash`` also refresh the sample hash and the shard's sha256 so only the content check is
    left to catch it. Returns the sample id."""
    manifest = json.loads((root / "manifest.json").read_text())
    j, i = divmod(k, manifest["shard_size"])
    path = root / shard_name(j)
    with h5py.File(path, "r+") as f:
        flow, exr_valid, header = decode_flow_exr(f["flow_exr"][i].tobytes())
        d = {
            "projected": f["projected"][i],
            "captured": f["captured"][i],
            "valid": f["valid"][i],
            "flow": flow,
            "exr_valid": exr_valid,
        }
        edit(d)
        sid = header["sample_id"]
        f["projected"][i], f["captured"][i], f["valid"][i] = d["projected"], d["captured"], d["valid"]
        f["flow_exr"][i] = np.frombuffer(encode_flow_exr(d["flow"], d["exr_valid"], sid), np.uint8)
        if rehash:
            params = json.loads(f["params"][i])
            digest = Sample(k, sid, d["projected"], d["captured"], d["flow"], d["valid"], params).content_hash()
            f["sample_hash"][i] = digest
            manifest["samples"][k]["sha256"] = digest
    manifest["shards"][j]["sha256"] = file_sha256(path)
    manifest["shards"][j]["bytes"] = path.stat().st_size
    (root / "manifest.json").write_text(json.dumps(manifest))
    return sid


def _valid_pixel(d: dict) -> tuple[int, int]:
    ys, xs = np.nonzero(d["valid"])
    return ys[len(ys) // 2], xs[len(xs) // 2]


def _nan_flow(d):
    d["flow"][_valid_pixel(d)] = (np.nan, 0.0)


def _flow_at_invalid(d):
    ys, xs = np.nonzero(~d["valid"])
    d["flow"][ys[0], xs[0]] = (0.5, 0.0)


def _flow_out_of_frame(d):
    d["flow"][_valid_pixel(d)] = (1000.0, 0.0)


def _valid_channel_mismatch(d):
    d["exr_valid"] = d["exr_valid"].copy()
    d["exr_valid"][_valid_pixel(d)] = False


CONTENT_DAMAGE = [
    (_nan_flow, "flow has NaN or Inf"),
    (_flow_at_invalid, "non-zero flow at invalid pixels"),
    (_flow_out_of_frame, "valid pixels whose flow leaves the camera frame"),
    (_valid_channel_mismatch, "EXR valid channel differs from the valid dataset"),
]


@pytest.mark.parametrize(("edit", "message"), CONTENT_DAMAGE, ids=[m for _, m in CONTENT_DAMAGE])
def test_content_checks_behind_the_hashes(cli, planar_ds, copy_dataset, edit, message):
    root = copy_dataset(planar_ds)
    k = 35  # shard 4 (the last), sample 3: has valid and invalid pixels
    _tamper(root, k, edit)
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert len(lines) == 1, lines
    assert str(root / shard_name(4)) in lines[0] and message in lines[0]


def test_changed_pixel_with_a_refreshed_file_hash_is_caught_by_the_sample_hash(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)

    def bump(d):
        d["captured"] = d["captured"].copy()
        d["captured"][10, 20, 1] ^= 1

    sid = _tamper(root, 9, bump, rehash=False)
    lines = _problems(cli, cli.run("verify", root, "-q"))
    assert lines == [
        f"projsynth: verify: {root / shard_name(1)}: sample 1 ({sid}): content hash differs from the manifest"
    ]


# --- inspect ----------------------------------------------------------------------------------------


def test_inspect_json_matches_a_recount(cli, mixed_ds):
    result = cli.run("inspect", mixed_ds, "--json")
    assert result.exit_code == 0, result.stderr
    report = json.loads(result.stdout)
    manifest = cli.manifest(mixed_ds)
    h, w = manifest["size"]

    assert sorted(report["families"]) == sorted(cli.MIXED_FAMILIES)
    assert report["total"]["samples"] == manifest["num_samples"] == 16
    assert sum(r["samples"] for r in report["families"].values()) == 16
    assert all(r["samples"] == 2 for r in report["families"].values())  # one transform each, two roles
    for name, r in [*report["families"].items(), ("total", report["total"])]:
        assert abs(sum(r["bucket_share"].values()) - 1) < 1e-3, name
        assert 0 < r["valid_share"] <= 1, name
        pixels = r["samples"] * h * w  # the histogram counts every valid pixel once (valid_share has 4 digits)
        assert abs(sum(r["histogram"]) - r["valid_share"] * pixels) <= 5e-5 * pixels + 1e-6, name

    # recount from the samples themselves
    counts: dict[str, np.ndarray] = {}
    reader = ShardReader(mixed_ds)
    try:
        for k in range(len(reader)):
            s = reader.read(k)
            mag = np.hypot(s["flow"][..., 0], s["flow"][..., 1])[s["valid"]]
            c = np.array([s["valid"].size, mag.size, *(int(m.sum()) for m in bucket_of(mag))])
            fam = s["params"]["transform"]["family"]
            counts[fam] = counts.get(fam, 0) + c
    finally:
        reader.close()
    counts["total"] = sum(counts.values())
    for name, (pixels, valid, *buckets) in counts.items():
        r = report["total"] if name == "total" else report["families"][name]
        assert r["valid_share"] == pytest.approx(valid / pixels, abs=5e-5), name
        for bucket, c in zip(("s0-10", "s10-40", "s40+"), buckets, strict=True):
            assert r["bucket_share"][bucket] == pytest.approx(c / valid, abs=5e-5), (name, bucket)


def test_inspect_table(cli, mixed_ds):
    result = cli.run("inspect", mixed_ds)
    assert result.exit_code == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"{mixed_ds}: 16 samples, size 48x64") and "{" not in lines[0]  # no raw dict
    table = lines[3 : lines.index("", 3)]
    rows = {line.split()[0]: line.split()[1] for line in table}
    assert rows == {**{f: "2" for f in cli.MIXED_FAMILIES}, "TOTAL": "16"}
    # the histogram docs/cli/projsynth.md promises: one row of shares per family and in total, then bars
    start = lines.index("flow magnitude histogram (px), share of valid pixels:")
    assert lines[start + 1].split() == ["family", "0-2", "2-5", "5-10", "10-20", "20-40", "40-80", "80-160", "160+"]
    hist = {line.split()[0]: line.split()[1:] for line in lines[start + 2 : start + 2 + len(rows)]}
    assert set(hist) == set(rows) and all(len(v) == 8 for v in hist.values())
    report = cli.run("inspect", mixed_ds, "--json")
    total = json.loads(report.stdout)["total"]["histogram"]
    assert hist["TOTAL"] == [f"{h / sum(total):.1%}" for h in total]


# --- export and preview -----------------------------------------------------------------------------

SUFFIXES = ("_projected.png", "_captured.png", "_valid.png", "_flow.exr", "_flow.flo", "_flow.png")


def _rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img.ndim == 3 else img


def test_export_writes_six_faithful_files_per_sample(cli, mixed_ds, tmp_path):
    out = tmp_path / "export"
    result = cli.run("export", mixed_ds, "--out", out, "--limit", "7")  # crosses the first shard (5)
    assert result.exit_code == 0, result.stderr
    assert f"{out}: 7 samples exported" in result.stderr
    manifest = cli.manifest(mixed_ds)
    ids = [s["id"] for s in manifest["samples"][:7]]
    assert sorted(p.name for p in out.iterdir()) == sorted(i + s for i in ids for s in SUFFIXES)

    h, w = manifest["size"]
    for k, sid in enumerate(ids):
        j, i = divmod(k, manifest["shard_size"])
        with h5py.File(mixed_ds / shard_name(j), "r") as f:
            stored = f["flow_exr"][i].tobytes()
            projected, captured, valid = f["projected"][i], f["captured"][i], f["valid"][i]
        assert (out / f"{sid}_flow.exr").read_bytes() == stored
        flow, _, _ = decode_flow_exr(stored)
        flo = read_flo(out / f"{sid}_flow.flo")
        assert flo.shape == (h, w, 2)
        np.testing.assert_array_equal(flo[valid], flow[valid])
        assert (flo[~valid] >= FLO_UNKNOWN * 0.999).all()
        np.testing.assert_array_equal(_rgb(out / f"{sid}_projected.png"), projected)
        np.testing.assert_array_equal(_rgb(out / f"{sid}_captured.png"), captured)
        np.testing.assert_array_equal(_rgb(out / f"{sid}_valid.png"), valid.astype(np.uint8) * 255)
        picture = _rgb(out / f"{sid}_flow.png")
        colour = picture[:h]  # the legend strip below
        assert picture.shape[0] > h and colour.shape == (h, w, 3) and (colour[~valid] == 0).all()  # invalid black
        assert colour[valid].any() or not valid.any()  # (sample 5 here has no valid pixel at all)
        np.testing.assert_array_equal(colour, flow_to_color(flow, valid))


def test_export_limit_larger_than_the_dataset(cli, mixed_ds, tmp_path):
    result = cli.run("export", mixed_ds, "--out", tmp_path / "all", "--limit", "100")
    assert result.exit_code == 0 and "16 samples exported" in result.stderr
    assert len(list((tmp_path / "all").iterdir())) == 16 * 6


@pytest.mark.parametrize("count", [3, 40])
def test_preview_sheet(cli, mixed_ds, tmp_path, count):
    out = tmp_path / "sub" / "sheet.png"
    result = cli.run("preview", mixed_ds, "--out", out, "--count", count)
    rows = min(count, 16)
    assert result.exit_code == 0, result.stderr
    assert f"{out}: {rows} samples" in result.stderr
    sheet = _rgb(out)
    h, w = cli.manifest(mixed_ds)["size"]
    lh = label_height(w)  # the header, and each row's label strip above its pictures
    assert sheet.shape[1] == 4 * w and sheet.shape[0] > lh + rows * (lh + h)  # + the legend
    reader = ShardReader(mixed_ds)
    try:
        for r, k in enumerate(np.linspace(0, 15, rows).astype(int)):
            s = reader.read(int(k))
            row = sheet[lh + r * (lh + h) + lh : lh + (r + 1) * (lh + h)]  # the pictures are not drawn over
            np.testing.assert_array_equal(row[:, :w], s["projected"])
            np.testing.assert_array_equal(row[:, w : 2 * w], s["captured"])
            np.testing.assert_array_equal(row[:, 2 * w : 3 * w], flow_to_color(s["flow"], s["valid"]))
            np.testing.assert_array_equal(row[:, 3 * w :, 0], s["valid"].astype(np.uint8) * 255)
    finally:
        reader.close()


def test_preview_and_export_with_a_fixed_flow_scale(cli, mixed_ds, tmp_path):
    """--max-flow: every picture saturates at the same magnitude, so two can be compared."""
    h, w = cli.manifest(mixed_ds)["size"]
    result = cli.run("preview", mixed_ds, "--out", tmp_path / "sheet.png", "--count", 2, "--max-flow", 50)
    assert result.exit_code == 0, result.stderr
    lh = label_height(w)
    reader = ShardReader(mixed_ds)
    try:
        s = reader.read(0)
    finally:
        reader.close()
    row = _rgb(tmp_path / "sheet.png")[2 * lh : 2 * lh + h]
    np.testing.assert_array_equal(row[:, 2 * w : 3 * w], flow_to_color(s["flow"], s["valid"], 50.0))
    assert cli.run("export", mixed_ds, "--out", tmp_path / "x", "--limit", 1, "--max-flow", 50, "-q").exit_code == 0
    exported = _rgb(tmp_path / "x" / f"{s['params']['sample_id']}_flow.png")
    np.testing.assert_array_equal(exported[:h], flow_to_color(s["flow"], s["valid"], 50.0))
    for command, options in (("preview", ["--out", tmp_path / "p.png"]), ("export", ["--out", tmp_path / "y"])):
        cli.assert_one_line_error(cli.run(command, mixed_ds, *options, "--max-flow", 0), "--max-flow")
    assert not (tmp_path / "p.png").exists() and not (tmp_path / "y").exists()


def test_preview_refuses_a_name_that_is_not_png(cli, mixed_ds, tmp_path):
    for name in ("sheet", "sheet.jpg"):
        cli.assert_one_line_error(cli.run("preview", mixed_ds, "--out", tmp_path / name), "--out", ".png")
    assert not list(tmp_path.iterdir())


def test_damaged_flow_in_a_shard_is_one_line_for_inspect_export_preview(cli, planar_ds, copy_dataset, tmp_path):
    root = copy_dataset(planar_ds)
    shard = root / shard_name(0)
    with h5py.File(shard, "r+") as f:
        f["flow_exr"][0] = np.frombuffer(b"\x76\x2f\x31\x01 not the rest of an EXR file", np.uint8)
    runs = {"inspect": [], "export": ["--out", tmp_path / "x", "-q"], "preview": ["--out", tmp_path / "p.png"]}
    for command, options in runs.items():
        line = cli.assert_one_line_error(cli.run(command, root, *options), shard, "sample 0", "projsynth verify")
        assert "flow_exr fails its CRC-32" in line, line
    assert not (tmp_path / "p.png").exists() and not list((tmp_path / "x").iterdir())
