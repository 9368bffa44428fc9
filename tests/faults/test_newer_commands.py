"""Issue 30: the bad-input and fault probe of the newer commands (patterns, capture, decode, bench's
reports, compensate, the onnxruntime backend, export, tracking). One case per defect; each failed on
the code before the fix."""

import json
import shutil

import cv2
import numpy as np
import pytest

from projreg import ProjregError
from projreg.inference.runtime import flows_resized
from projreg.model.checkpoint import reference_checkpoint
from projsynth.flow.formats import read_flow_exr, write_flow_exr

SIZE = "96x128"


@pytest.fixture(scope="module")
def rig(tmp_path_factory, probe):
    """``(patterns, photos)``: a graycode set at 96 x 128 and its photos through transform 3."""
    root = tmp_path_factory.mktemp("rig")
    pat, cap = root / "pat", root / "cap"
    assert probe.projsynth("patterns", "--kind", "graycode", "--size", SIZE, "--out", pat).exit_code == 0
    result = probe.projsynth("capture", "--patterns", pat, "--out", cap, "--transform", "3")
    assert result.exit_code == 0, result.stderr
    return pat, cap


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_1_capture_into_the_patterns_folder_is_refused(probe, rig, tmp_path):
    pat = shutil.copytree(rig[0], tmp_path / "pat")
    before = _snapshot(pat)
    for out in (pat, f"{pat}/.", tmp_path / "x" / ".." / "pat"):
        (tmp_path / "x").mkdir(exist_ok=True)
        probe.error(probe.projsynth("capture", "--patterns", pat, "--out", out, "--transform", "3"), "--patterns")
    assert _snapshot(pat) == before


def test_2_bench_reports_never_overwrite_the_dataset_or_the_model(probe, d_copy, tmp_path):
    before = _snapshot(d_copy)
    model = tmp_path / "ref.pt"
    shutil.copy(reference_checkpoint(), model)
    quick = ["--baselines", "dis-fast", "--refine", "off", "--limit", "1"]
    cases = [
        ("--json", d_copy / "manifest.json", []),
        ("--markdown", d_copy / "shard-00000.h5", []),
        ("--json", model, ["--model", model]),
    ]
    for option, target, extra in cases:
        line = probe.error(probe.projreg("bench", "--data", d_copy, option, target, *extra, *quick), option)
        assert "is the input" in line
    assert _snapshot(d_copy) == before
    assert model.read_bytes() == reference_checkpoint().read_bytes()
    same = tmp_path / "r.json"
    probe.error(probe.projreg("bench", "--data", d_copy, "--json", same, "--markdown", same, *quick), "own file")


@pytest.mark.parametrize("command", ["patterns", "capture", "decode"])
def test_3_an_empty_out_is_refused(probe, rig, tmp_path, command):
    pat, cap = rig
    args = {
        "patterns": ["--kind", "graycode", "--size", SIZE],
        "capture": ["--patterns", pat, "--transform", "3"],
        "decode": ["--patterns", pat, "--captures", cap],
    }[command]
    result = probe.process("projsynth", command, *args, "--out", "", cwd=tmp_path)
    probe.error(result, "--out", "empty")
    assert not list(tmp_path.iterdir())


def test_4_pattern_counts_are_bounded(probe, tmp_path):
    out = tmp_path / "p"
    probe.error(
        probe.projsynth("patterns", "--kind", "graycode", "--size", SIZE, "--shifts", "100000", "--out", out),
        "--shifts",
        "3..64",
    )
    probe.error(
        probe.projsynth("patterns", "--kind", "graycode", "--size", SIZE, "--period", "100000", "--out", out),
        "--period",
    )
    assert not out.exists()


@pytest.mark.parametrize(
    "edit",
    [
        {"size": [-96, 128]},
        {"size": [0, 0]},
        {"size": [60000, 80000]},
        {"size": "96x128"},
        {"parameters.period": "16"},
        {"parameters.shifts": 100000},
        {"parameters.period": 16.0},
    ],
)
def test_5_an_edited_patterns_file_is_one_line_naming_it(probe, rig, tmp_path, edit):
    pat = shutil.copytree(rig[0], tmp_path / "pat")
    d = json.loads((pat / "patterns.json").read_text())
    for key, value in edit.items():
        where, _, leaf = key.rpartition(".")
        (d[where] if where else d)[leaf] = value
    (pat / "patterns.json").write_text(json.dumps(d))
    probe.error(
        probe.projsynth("decode", "--patterns", pat, "--captures", rig[1], "--out", tmp_path / "o"), "patterns.json"
    )
    assert not (tmp_path / "o").exists()


def test_5_an_edited_dots_file_names_its_key_not_an_option(probe, tmp_path, rig):
    pat = tmp_path / "dots"
    assert probe.projsynth("patterns", "--kind", "dots", "--size", SIZE, "--grid", "5x5", "--out", pat).exit_code == 0
    d = json.loads((pat / "patterns.json").read_text())
    d["parameters"]["grid"] = [40, 40]
    (pat / "patterns.json").write_text(json.dumps(d))
    line = probe.error(
        probe.projsynth("decode", "--patterns", pat, "--captures", rig[1], "--out", tmp_path / "o"),
        'patterns.json: "grid"',
    )
    assert "--grid" not in line


@pytest.mark.parametrize("seed", ["-5", str(2**64)])
def test_6_capture_seed_is_range_checked(probe, rig, tmp_path, seed):
    out = tmp_path / "k"
    probe.error(
        probe.projsynth("capture", "--patterns", rig[0], "--out", out, "--transform", "3", "--seed", seed), "--seed"
    )
    assert not out.exists()


def test_7_decode_of_black_photos_is_refused(probe, rig, tmp_path):
    pat, cap = rig
    black = tmp_path / "black"
    black.mkdir()
    for photo in cap.glob("[0-9]*.png"):
        cv2.imwrite(str(black / photo.name), np.zeros((96, 128, 3), np.uint8))
    out = tmp_path / "o"
    line = probe.error(
        probe.projsynth(
            "decode",
            "--patterns",
            pat,
            "--captures",
            black,
            "--out",
            out,
            "--pair",
            pat / "00-white.png",
            cap / "00-white.png",
        ),
        "--captures",
        "exposure",
    )
    assert "0.0%" in line
    assert not out.exists()


def test_7_bench_reports_a_dataset_without_valid_pixels(probe, rig, tmp_path):
    from projsynth.structured.captured import captured_samples, write_captured_dataset
    from projsynth.structured.patterns import read_patterns

    pat, cap = rig
    photos = sorted(cap.glob("[0-9]*.png"))
    flow, valid = np.zeros((96, 128, 2), np.float32), np.zeros((96, 128), bool)
    samples = captured_samples([(pat / "00-white.png", cap / "04-gray-x3.png")], flow, valid, (96, 128))
    write_captured_dataset(tmp_path / "d", read_patterns(pat), pat, photos, samples, (96, 128))
    result = probe.projreg(
        "bench",
        "--data",
        tmp_path / "d",
        "--baselines",
        "dis-fast,sift-ransac",
        "--refine",
        "both",
        "--json",
        tmp_path / "r.json",
        "--markdown",
        tmp_path / "r.md",
    )
    assert result.exit_code == 0, (result.stderr, result.exception)
    report = json.loads((tmp_path / "r.json").read_text())
    assert all(r["epe"] is None for r in report["results"])


@pytest.fixture
def photos(tmp_path):
    """A white photo (a bright, textured surface) and a black one (dim ambient light), 48 x 64."""
    rng = np.random.default_rng(1)
    white = rng.integers(150, 240, (48, 64, 3), np.uint8)
    black = rng.integers(5, 30, (48, 64, 3), np.uint8)
    paths = tmp_path / "white.png", tmp_path / "black.png"
    for path, image in zip(paths, (white, black), strict=True):
        cv2.imwrite(str(path), image)
    return paths


def _identity_flow(tmp_path, value=None):
    flow = np.zeros((48, 64, 2), np.float32)
    if value is not None:
        flow[:, :20, 0] = value
    write_flow_exr(tmp_path / "f.exr", flow, np.ones((48, 64), bool), "probe")
    return tmp_path / "f.exr"


def _compensate(probe, tmp_path, *options):
    """``projreg compensate`` of a grey view through the identity flow into ``tmp_path/p.png``."""
    content = tmp_path / "c.png"
    cv2.imwrite(str(content), np.full((48, 64, 3), 128, np.uint8))
    flow = _identity_flow(tmp_path)
    return probe.projreg("compensate", "--content", content, "--flow", flow, "--out", tmp_path / "p.png", *options)


def test_8_swapped_white_and_black_photos_are_refused(probe, tmp_path, photos):
    white, black = photos
    result = _compensate(probe, tmp_path, "--photometric", "--white", black, "--black", white)
    assert "100%" in probe.error(result, "--white", "swapped")
    assert not (tmp_path / "p.png").exists()


def test_f_a_clipped_white_photo_is_a_warning(probe, tmp_path, photos):
    cv2.imwrite(str(photos[0]), np.full((48, 64, 3), 255, np.uint8))
    result = _compensate(probe, tmp_path, "--photometric", "--white", photos[0], "--black", photos[1])
    assert result.exit_code == 0, result.stderr
    assert "projreg: warning: --white" in result.stderr and "saturated on 100%" in result.stderr


@pytest.mark.parametrize("far", [1e30, -1e6, 64.0])
def test_9_flow_landing_outside_the_camera_frame_is_filled(probe, tmp_path, far):
    content, out = tmp_path / "c.png", tmp_path / "p.png"
    cv2.imwrite(str(content), np.random.default_rng(2).integers(0, 255, (48, 64, 3), np.uint8))
    result = probe.projreg(
        "compensate", "--content", content, "--flow", _identity_flow(tmp_path, far), "--out", out, "--fill", "77"
    )
    assert result.exit_code == 0, result.stderr
    projector = cv2.imread(str(out))
    assert (projector[:, :20] == 77).all()
    assert "content on 68.8%" in result.stderr  # 44 of 64 columns


def _graph(path, output):
    """An ONNX graph with the inputs and output names of `projreg export --onnx`: ``output`` ``nan``
    gives a NaN flow of the right shape, ``rgb`` the projected image itself (3 channels)."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper

    image = ["N", 3, "H", "W"]
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, image) for n in ("projected", "captured")]
    if output == "nan":
        nodes = [
            helper.make_node("Slice", ["projected", "zero", "two", "one"], ["uv"]),
            helper.make_node("Mul", ["uv", "nan"], ["flow"]),
        ]
        inits = [
            helper.make_tensor("zero", TensorProto.INT64, [1], [0]),
            helper.make_tensor("two", TensorProto.INT64, [1], [2]),
            helper.make_tensor("one", TensorProto.INT64, [1], [1]),
            helper.make_tensor("nan", TensorProto.FLOAT, [], [float("nan")]),
        ]
        shape = ["N", 2, "H", "W"]
    else:
        nodes, inits, shape = [helper.make_node("Identity", ["projected"], ["flow"])], [], image
    out = helper.make_tensor_value_info("flow", TensorProto.FLOAT, shape)
    model = helper.make_model(
        helper.make_graph(nodes, "g", inputs, [out], inits), opset_imports=[helper.make_opsetid("", 18)]
    )
    onnx.save(model, str(path))
    return path


@pytest.mark.parametrize("output, needle", [("nan", "not finite"), ("rgb", "shape")])
def test_10_and_b_a_foreign_or_broken_graph_is_refused(probe, rig, tmp_path, output, needle):
    graph = _graph(tmp_path / "g.onnx", output)
    out = tmp_path / "f.exr"
    for refine in ("--no-refine", "--refine"):
        result = probe.projreg(
            "predict",
            "--projected",
            rig[0] / "00-white.png",
            "--captured",
            rig[1] / "00-white.png",
            "--out",
            out,
            "--model",
            graph,
            "--backend",
            "onnxruntime",
            refine,
        )
        probe.error(result, f"--model {graph}", needle)
    assert not out.exists()


def test_10_a_non_finite_flow_is_refused_whatever_the_backend():
    def broken(a, b):
        return np.full((*a.shape[:3], 2), np.inf, np.float32)

    pair = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(ProjregError, match="not finite"):
        flows_resized(broken, [(pair, pair)], 1024)


def test_a_a_tracked_sequence_that_changes_size_is_refused_before_writing(probe, rig, tmp_path):
    proj, cap, out = tmp_path / "p", tmp_path / "c", tmp_path / "o"
    proj.mkdir(), cap.mkdir()
    for i, name in enumerate(("00-white", "04-gray-x3", "08-gray-x1")):
        shutil.copy(rig[0] / f"{name}.png", proj / f"f{i}.png")
        shutil.copy(rig[1] / f"{name}.png", cap / f"f{i}.png")
    cv2.imwrite(str(cap / "f2.png"), np.zeros((80, 128, 3), np.uint8))
    result = probe.projreg("predict", "--projected", proj, "--captured", cap, "--out", out, "--track", "--quiet")
    probe.error(result, cap / "f2.png", "128x80", "nothing was written")
    assert not out.exists()


def test_c_damaged_files_are_one_line_without_the_decoders_noise(probe, rig, tmp_path):
    png = tmp_path / "t.png"
    png.write_bytes((rig[1] / "00-white.png").read_bytes()[:3000])
    write_flow_exr(tmp_path / "f.exr", np.zeros((96, 128, 2), np.float32), np.ones((96, 128), bool), "x")
    exr = tmp_path / "t.exr"
    exr.write_bytes((tmp_path / "f.exr").read_bytes()[:500])
    for content, flow, needle in ((png, tmp_path / "f.exr", png), (rig[1] / "00-white.png", exr, exr)):
        result = probe.process(
            "projreg", "compensate", "--content", content, "--flow", flow, "--out", tmp_path / "o.png"
        )
        probe.error(result, needle)
        assert result.stdout == ""


def test_e_options_of_another_mode_are_refused(probe, tmp_path, photos):
    for kind, extra in (("graycode", ["--grid", "5x5"]), ("dots", ["--shifts", "4"])):
        result = probe.projsynth("patterns", "--kind", kind, "--size", SIZE, *extra, "--out", tmp_path / "p")
        probe.error(result, extra[0])
    probe.error(_compensate(probe, tmp_path, "--white", photos[0]), "--photometric")
    assert not (tmp_path / "p.png").exists() and not (tmp_path / "p").exists()


def test_g_a_rerun_removes_what_a_killed_decode_left(probe, rig, tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    stale = [out / ".correspondence.exr.0123456789ab.tmp", out / ".decode.json.ba9876543210.tmp"]
    for path in stale:
        path.write_bytes(b"half")
    assert probe.projsynth("decode", "--patterns", rig[0], "--captures", rig[1], "--out", out).exit_code == 0
    assert not any(p.exists() for p in stale)
    assert sorted(p.name for p in out.iterdir()) == ["correspondence.exr", "decode.json"]


def test_h_decode_json_is_written_last(probe, rig, tmp_path, monkeypatch):
    import projsynth.structured.decode

    out = tmp_path / "o"
    args = [
        "decode",
        "--patterns",
        rig[0],
        "--captures",
        rig[1],
        "--out",
        out,
        "--pair",
        rig[0] / "00-white.png",
        rig[1] / "00-white.png",
    ]
    assert probe.projsynth(*args).exit_code == 0

    def killed(*a, **k):
        raise RuntimeError("killed")  # as a kill between the correspondence and the dataset

    monkeypatch.setattr(projsynth.structured.decode, "write_captured_dataset", killed)
    probe.projsynth(*args)
    assert (out / "correspondence.exr").exists() and not (out / "decode.json").exists()
    flow, valid, _ = read_flow_exr(out / "correspondence.exr")
    assert valid.mean() > 0.5
