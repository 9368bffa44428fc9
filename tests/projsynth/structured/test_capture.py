"""The virtual rig (``projsynth capture``) and the decode path end to end, measured against exact truth."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import read_flow_exr
from projsynth.sim.render import ground_truth
from projsynth.sim.scene import MISS, OCCLUDED, OUT_OF_FRAME
from projsynth.structured.capture import make_rig, shoot
from projsynth.structured.decode import decode
from projsynth.structured.patterns import make_set

SIZE, CAMERA = (120, 160), (150, 200)
# one transform of each geometry family, studio/night/daylight/translucent light (not the extreme "noisy")
FAMILY_IDS = [0, 26, 45, 67, 85, 106, 125, 146]


@pytest.mark.parametrize("tid", FAMILY_IDS)
def test_graycode_decode_against_exact_truth(tid):
    table = builtin_table()
    assert table.configs[tid].condition != "noisy"
    patterns = make_set("graycode", SIZE)
    rig = make_rig(table, tid, seed=7, size=SIZE, camera_size=CAMERA)
    photos = np.stack([shoot(rig, img, 7, i) for i, img in enumerate(patterns.images())])
    result = decode(patterns, photos.mean(axis=3, dtype=np.float32) / 255)
    flow, valid, reason = ground_truth(rig.scene)
    both = result.valid & valid
    err = np.hypot(*(result.flow - flow)[both].T)
    assert both.sum() >= 0.85 * valid.sum(), (tid, both.sum() / valid.sum())
    assert np.median(err) <= 0.05 and np.percentile(err, 95) <= 0.3, (tid, np.median(err), np.percentile(err, 95))
    wrong_place = result.valid & ((reason & (MISS | OUT_OF_FRAME | OCCLUDED)) > 0)
    assert wrong_place.sum() <= 0.001 * result.valid.sum(), (tid, wrong_place.sum())


def test_a_larger_camera_sees_the_same_view_with_more_pixels():
    table = builtin_table()
    for tid in (30, 125):  # lens distortion; a wave
        small = make_rig(table, tid, 3, SIZE, SIZE)
        large = make_rig(table, tid, 3, SIZE, (SIZE[0] * 2, SIZE[1] * 2))
        f1, v1, _ = ground_truth(small.scene)
        f2, v2, _ = ground_truth(large.scene)
        ys, xs = np.mgrid[0 : SIZE[0], 0 : SIZE[1]]
        grid = np.stack([xs, ys], -1)
        both = v1 & v2
        # pixel centres at integers: camera position u at 1x is 2 (u + 0.5) - 0.5 at 2x
        np.testing.assert_allclose((f2 + grid)[both], 2 * ((f1 + grid)[both] + 0.5) - 0.5, atol=2e-4)
        assert both.sum() >= 0.97 * v1.sum()


def test_capture_is_reproducible_and_records_its_scene(tmp_path, cli):
    pat = tmp_path / "pat"
    assert cli.run("patterns", "--kind", "dots", "--size", "240x320", "--out", pat).exit_code == 0
    runs = []
    for name in ("a", "b"):
        result = cli.run(
            "capture",
            "--patterns",
            pat,
            "--out",
            tmp_path / name,
            "--transform",
            "45",
            "--seed",
            "2",
            "--camera-size",
            "300x400",
        )
        assert result.exit_code == 0, result.stderr
        runs.append(tmp_path / name)
    photos = sorted(p.name for p in runs[0].glob("*.png"))
    assert len(photos) == 11 and photos[0] == "00-on.png"
    for name in photos:
        assert (runs[0] / name).read_bytes() == (runs[1] / name).read_bytes()
    record = json.loads((runs[0] / "capture.json").read_text())
    assert record["camera_size"] == [300, 400] and record["transform"]["family"] == "cylinder_convex"
    assert cv2.imread(str(runs[0] / photos[0])).shape == (300, 400, 3)


@pytest.fixture(scope="module")
def rig_run(tmp_path_factory):
    """``patterns`` + ``capture`` with a picture: the photos alone in ``photos/`` (as a user has them)."""
    from typer.testing import CliRunner

    from projsynth.cli import app

    root = tmp_path_factory.mktemp("rig")
    picture = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    cv2.imwrite(str(root / "picture.png"), cv2.resize(picture, (160, 120), interpolation=cv2.INTER_CUBIC))
    runner = CliRunner()
    for args in (
        ["patterns", "--kind", "graycode", "--size", "120x160", "--out", root / "pat"],
        [
            "capture",
            "--patterns",
            root / "pat",
            "--out",
            root / "cap",
            "--transform",
            "85",
            "--camera-size",
            "150x200",
            "--content",
            root / "picture.png",
        ],
    ):
        result = runner.invoke(app, [str(a) for a in args])
        assert result.exit_code == 0, result.stderr
    (root / "photos").mkdir()
    for p in (root / "cap").glob("[0-9]*.png"):
        shutil.copy(p, root / "photos" / p.name)
    return root


def test_decode_with_pairs_makes_a_dataset_every_tool_reads(rig_run, cli, tmp_path):
    out = tmp_path / "real"
    content = rig_run / "cap" / "content"
    result = cli.run(
        "decode",
        "--patterns",
        rig_run / "pat",
        "--captures",
        rig_run / "photos",
        "--out",
        out,
        "--pair",
        content / "picture-projected.png",
        content / "picture.png",
    )
    assert result.exit_code == 0, result.stderr
    flow, valid, _ = read_flow_exr(out / "correspondence.exr")
    truth, truth_valid, _ = read_flow_exr(rig_run / "cap" / "truth.exr")
    both = valid & truth_valid
    assert np.median(np.hypot(*(flow - truth)[both].T)) < 0.05
    assert cli.run("verify", out).exit_code == 0
    report = json.loads(cli.run("inspect", out, "--json").stdout)
    assert report["config"]["camera_size"] == [150, 200] and "captured" in report["families"]
    assert cli.run("export", out, "--out", tmp_path / "files", "-q").exit_code == 0
    assert cv2.imread(str(tmp_path / "files" / "captured-p00000_captured.png")).shape == (150, 200, 3)
    assert cli.run("preview", out, "--out", tmp_path / "sheet.png").exit_code == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["captured"]["patterns_kind"] == "graycode" and len(manifest["captured"]["photos"]) == len(
        list((rig_run / "photos").iterdir())
    )


def _photos_copy(rig_run: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "photos"
    shutil.copytree(rig_run / "photos", dst)
    return dst


@pytest.mark.parametrize("damage", ["missing", "extra", "size", "unreadable", "pair-size"])
def test_bad_photos_are_one_clear_error(rig_run, cli, tmp_path, damage):
    photos = _photos_copy(rig_run, tmp_path)
    extra: list = []
    needle = ""
    if damage == "missing":
        (photos / "05-gray-x4-inv.png").unlink()
        needle = "05-gray-x4-inv"
    elif damage == "extra":
        shutil.copy(photos / "00-white.png", photos / "holiday.jpg.png")
        needle = "holiday"
    elif damage == "size":
        img = cv2.imread(str(photos / "07-gray-x3-inv.png"))
        cv2.imwrite(str(photos / "07-gray-x3-inv.png"), img[:-2])
        needle = "07-gray-x3-inv"
    elif damage == "unreadable":
        (photos / "03-gray-x5-inv.png").write_bytes(b"not a png")
        needle = "03-gray-x5-inv"
    else:
        content = rig_run / "cap" / "content"
        extra = ["--pair", content / "picture-projected.png", rig_run / "picture.png"]
        needle = "picture.png"
    result = cli.run("decode", "--patterns", rig_run / "pat", "--captures", photos, "--out", tmp_path / "o", *extra)
    cli.assert_one_line_error(result, needle)
    assert not (tmp_path / "o" / "manifest.json").exists()


def test_decode_refuses_a_folder_of_other_files_and_rewrites_its_own(rig_run, cli, tmp_path):
    decode = ["decode", "--patterns", rig_run / "pat", "--captures", rig_run / "photos", "--out"]
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "notes.txt").write_text("the rig's settings")
    line = cli.assert_one_line_error(cli.run(*decode, notes), f"--out {notes}: holds 1 file(s)", "(e.g. notes.txt)")
    assert "not written by `projsynth decode`" in line and "choose a new or empty folder" in line
    dataset = tmp_path / "dataset"  # a `gen` dataset: names decode writes with --pair, but not its output
    dataset.mkdir()
    for name in ("dataset.json", "manifest.json", "shard-00000.h5"):
        (dataset / name).write_text("{}")
    cli.assert_one_line_error(cli.run(*decode, dataset), f"--out {dataset}: holds 3 file(s)", "(e.g. dataset.json)")
    for folder, names in ((notes, ["notes.txt"]), (dataset, ["dataset.json", "manifest.json", "shard-00000.h5"])):
        assert sorted(p.name for p in folder.iterdir()) == names
    out = tmp_path / "out"  # names beginning with a dot, which file managers hide, are not counted
    out.mkdir()
    (out / ".DS_Store").write_bytes(b"finder")
    assert cli.run(*decode, out).exit_code == 0
    first = (out / "correspondence.exr").read_bytes()
    result = cli.run(*decode, out)  # its own earlier output: decoded again
    assert result.exit_code == 0, result.stderr
    assert (out / "correspondence.exr").read_bytes() == first
    assert sorted(p.name for p in out.iterdir()) == [".DS_Store", "correspondence.exr", "decode.json"]


def test_decode_refuses_another_dataset_before_touching_its_earlier_output(rig_run, cli, tmp_path):
    out = tmp_path / "real"
    decode = ["decode", "--patterns", rig_run / "pat", "--captures", rig_run / "photos", "--out", out, "--pair"]
    content = rig_run / "cap" / "content"
    assert cli.run(*decode, content / "picture-projected.png", content / "picture.png").exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    other = [rig_run / "pat" / "00-white.png", rig_run / "photos" / "00-white.png"]
    cli.assert_one_line_error(cli.run(*decode, *other), f"--out {out}: holds another dataset")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # decode.json kept: still a finished decode
    (out / "dataset.json").write_text("[1]")
    cli.assert_one_line_error(cli.run(*decode, *other), f"{out / 'dataset.json'}: not a plan")
