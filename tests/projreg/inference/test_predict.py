import json

import cv2
import numpy as np
import torch
from typer.testing import CliRunner

import projreg.inference.predict
import projreg.model.checkpoint
from projreg.api import Registrar
from projreg.cli import app
from projreg.model.checkpoint import load_model
from projreg.refine.refiner import GeometricRefiner
from projreg.training.validate import predict_flow
from projsynth.dataset.shards import ShardReader
from projsynth.flow.formats import read_flow_exr
from projsynth.flow.pictures import flow_to_color
from projsynth.structured.response import Response, projector_curve, response_record

CPU = torch.device("cpu")


def _write(path, rgb):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def _cli(*args):
    return CliRunner().invoke(app, ["predict", *(str(a) for a in args), "-q"])


def test_file_mode_writes_the_model_flow_as_exr_and_png(pairs, tiny_ckpt, tmp_path):
    img0, img1 = pairs[0]
    a, b = _write(tmp_path / "a.png", img0), _write(tmp_path / "b.png", img1)
    out, viz = tmp_path / "o" / "flow.exr", tmp_path / "flow.png"
    result = _cli("--projected", a, "--captured", b, "--out", out, "--viz", viz, "--model", tiny_ckpt)
    assert result.exit_code == 0, (result.stderr, result.exception)
    flow, valid, header = read_flow_exr(out)
    assert flow.shape == (64, 96, 2)
    assert header["sample_id"] == "a.png" and header["direction"] == "projected->captured"
    # the same numbers as the model then the refinement run directly on the arrays: order, channels and
    # direction wired right; valid is the refinement's confidence >= 0.5
    expected = GeometricRefiner().predict(img0, img1, predict_flow(load_model(tiny_ckpt, CPU), img0, img1, CPU))
    np.testing.assert_allclose(flow, expected.flow, atol=1e-4)
    np.testing.assert_array_equal(valid, expected.claimed)
    assert 0.3 < valid.mean() and header["registered"] == "yes" and float(header["claimed"]) == round(valid.mean(), 4)
    assert header["valid_threshold"] == "confidence >= 0.5" and "warning" not in result.stderr
    png = cv2.cvtColor(cv2.imread(str(viz)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(png[:64], flow_to_color(flow, valid))  # the legend strip below
    assert png.shape[0] > 64 and png.shape[1] == 96
    assert not [p for p in tmp_path.rglob("*.tmp")]


def test_folder_mode_pairs_by_relative_name(pairs, tiny_ckpt, tmp_path):
    names = ["x.png", "sub/y.png"]
    for name, (img0, img1) in zip(names, pairs, strict=True):
        _write(tmp_path / "P" / name, img0)
        _write(tmp_path / "C" / name, img1)
    out, viz = tmp_path / "out", tmp_path / "viz"
    folders = ["--projected", tmp_path / "P", "--captured", tmp_path / "C"]
    result = _cli(*folders, "--out", out, "--viz", viz, "--model", tiny_ckpt, "--no-refine")
    assert result.exit_code == 0, (result.stderr, result.exception)
    model = load_model(tiny_ckpt, CPU)
    for name, stem, (img0, img1) in zip(names, ["x_flow", "sub/y_flow"], pairs, strict=True):
        flow, valid, header = read_flow_exr(out / f"{stem}.exr")
        assert header["sample_id"] == name and valid.all()  # the network alone claims every pixel
        np.testing.assert_allclose(flow, predict_flow(model, img0, img1, CPU), atol=1e-4)
        assert (viz / f"{stem}.png").is_file()


def test_a_blank_pair_is_reported_on_stderr_and_left_invalid(pairs, tiny_ckpt, tmp_path):
    blank = np.full((64, 96, 3), 150, np.uint8)
    a, b = _write(tmp_path / "blank.png", blank), _write(tmp_path / "seen.png", pairs[0][1])
    out = tmp_path / "f.exr"
    result = _cli("--projected", a, "--captured", b, "--out", out, "--model", tiny_ckpt)
    assert result.exit_code == 0, (result.stderr, result.exception)
    (line,) = [x for x in result.stderr.splitlines() if x.strip()]
    assert line.startswith("projreg: warning: blank.png: cannot be registered (textureless") and str(out) in line
    flow, valid, header = read_flow_exr(out)
    assert not valid.any() and not flow.any()
    assert header["registered"] == "no" and "textureless" in header["reason"] and header["claimed"] == "0.0000"


def test_a_repeating_pattern_is_reported_as_such(tiny_ckpt, tmp_path):
    """A grating matched one period off passes every check: the pair is refused, and the user is told why."""
    y, x = np.mgrid[0:160, 0:224].astype(np.float32)
    grating = np.repeat((128 + 90 * np.sin(2 * np.pi * (x + 0.15 * y) / 9)).astype(np.uint8)[..., None], 3, axis=2)
    moved = cv2.remap(grating, x - 3, y - 2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    a, b = _write(tmp_path / "grating.png", grating), _write(tmp_path / "moved.png", moved)
    out = tmp_path / "f.exr"
    result = _cli("--projected", a, "--captured", b, "--out", out, "--model", tiny_ckpt)
    assert result.exit_code == 0, (result.stderr, result.exception)
    (line,) = [x for x in result.stderr.splitlines() if x.strip()]
    assert line.startswith("projreg: warning: grating.png: cannot be registered (repeating pattern: 100%"), line
    _, valid, header = read_flow_exr(out)
    assert not valid.any() and header["registered"] == "no" and header["reason"].startswith("repeating pattern")


def test_large_pairs_are_shrunk_and_the_flow_scaled_back(pairs, tiny_ckpt, tmp_path):
    img0, img1 = pairs[0]
    # pixel replication: INTER_AREA at 1/2 gives back exactly the original pair
    big0, big1 = (np.repeat(np.repeat(i, 2, axis=0), 2, axis=1) for i in (img0, img1))
    a, b = _write(tmp_path / "a.png", big0), _write(tmp_path / "b.png", big1)
    out = tmp_path / "f.exr"
    result = _cli(
        "--projected", a, "--captured", b, "--out", out, "--model", tiny_ckpt, "--max-side", "96", "--no-refine"
    )
    assert result.exit_code == 0, (result.stderr, result.exception)
    flow, _, _ = read_flow_exr(out)
    assert flow.shape == (128, 192, 2)
    small = predict_flow(load_model(tiny_ckpt, CPU), img0, img1, CPU)  # [64, 96, 2]
    assert np.median(np.abs(small)) > 0.1  # a meaningful comparison needs non-zero flow
    # each 2x2 block of the big flow, in big-image pixels, is twice the small flow at that pixel
    blocks = flow.reshape(64, 2, 96, 2, 2).mean(axis=(1, 3))
    rel = np.abs(blocks - 2 * small) / np.maximum(np.abs(2 * small), 1e-3)
    assert np.median(rel) < 0.1, np.median(rel)
    # exactly: the small flow, bilinearly enlarged, times W/w' = H/h' = 2
    np.testing.assert_allclose(flow, 2 * cv2.resize(small, (192, 128), interpolation=cv2.INTER_LINEAR), atol=1e-3)


def test_errors_are_one_line_naming_the_file(pairs, tiny_ckpt, tmp_path, monkeypatch, one_line_error):
    img0, img1 = pairs[0]
    a, b = _write(tmp_path / "a.png", img0), _write(tmp_path / "b.png", img1)
    out = tmp_path / "f.exr"
    m = ("--model", tiny_ckpt)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    one_line_error(_cli("--projected", a, "--captured", junk, "--out", out, *m), junk)
    one_line_error(_cli("--projected", tmp_path / "none.png", "--captured", b, "--out", out, *m), "none.png")
    for side in ("P", "C"):
        _write(tmp_path / side / "both.png", img0)
    lonely = _write(tmp_path / "C" / "lonely.png", img1)
    one_line_error(
        _cli("--projected", tmp_path / "P", "--captured", tmp_path / "C", "--out", tmp_path / "o", *m), lonely
    )
    one_line_error(_cli("--projected", tmp_path / "P", "--captured", b, "--out", out, *m), "--captured")
    one_line_error(_cli("--projected", a, "--captured", b, "--out", tmp_path / "f.png", *m), "--out", "ending in .exr")
    one_line_error(
        _cli("--projected", a, "--captured", b, "--out", out, "--viz", tmp_path / "v.exr", *m),
        "--viz",
        "ending in .png",
    )
    one_line_error(  # two image files are one pair: nothing to batch (it was ignored)
        _cli("--projected", a, "--captured", b, "--out", out, "--batch-size", 2, *m), "drop --batch-size"
    )
    empty = _cli("--projected", "", "--captured", b, "--out", out, *m)  # a usage error, not the current folder
    assert empty.exit_code == 2 and "Invalid value for '--projected': empty" in empty.stderr
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"a file where the --viz folder would be")
    one_line_error(_cli("--projected", a, "--captured", b, "--out", out, "--viz", blocker / "v.png", *m), blocker)
    assert not out.exists()  # the flow and its picture, or neither
    monkeypatch.setattr(projreg.model.checkpoint, "reference_checkpoint", lambda: None)
    one_line_error(_cli("--projected", a, "--captured", b, "--out", out), "no shipped reference model yet", "--model")


def test_track_mode_takes_the_frames_in_name_order_from_the_previous_flow(tiny_sequences, tiny_ckpt, tmp_path):
    reader = ShardReader(tiny_sequences)
    try:
        frames = [reader.read(k) for k in range(3)]  # one sequence
    finally:
        reader.close()
    for s in frames:
        name = f"{s['params']['frame']:02d}.png"
        _write(tmp_path / "P" / name, s["projected"])
        _write(tmp_path / "C" / name, s["captured"])
    out = tmp_path / "out"
    result = _cli(
        "--projected", tmp_path / "P", "--captured", tmp_path / "C", "--out", out, "--model", tiny_ckpt, "--track"
    )
    assert result.exit_code == 0, (result.stderr, result.exception)
    steps = [read_flow_exr(out / f"{i:02d}_flow.exr")[2]["tracking"] for i in range(3)]
    assert steps[0] == "full" and set(steps[1:]) <= {"tracked", "lost"}
    # the same as the tracker run directly
    from projreg.inference.track import Tracker

    model, refiner = load_model(tiny_ckpt, CPU), GeometricRefiner()
    tracker = Tracker(lambda a, b: refiner.predict(a, b, predict_flow(model, a, b, CPU)), refiner)
    for i, s in enumerate(frames):
        expected = tracker(s["projected"], s["captured"])
        assert tracker.last == steps[i]
        np.testing.assert_allclose(read_flow_exr(out / f"{i:02d}_flow.exr")[0], expected.flow, atol=1e-4)


def test_track_mode_errors_name_the_option(pairs, tiny_ckpt, tmp_path, one_line_error):
    a, b = _write(tmp_path / "a.png", pairs[0][0]), _write(tmp_path / "b.png", pairs[0][1])
    one_line_error(
        _cli("--projected", a, "--captured", b, "--out", tmp_path / "f.exr", "--model", tiny_ckpt, "--track"),
        "--track",
        "folders",
    )
    (tmp_path / "P").mkdir()
    (tmp_path / "C").mkdir()
    folders = ["--projected", tmp_path / "P", "--captured", tmp_path / "C"]
    result = _cli(*folders, "--out", tmp_path / "o", "--model", tiny_ckpt, "--track", "--no-refine")
    one_line_error(result, "--track", "--no-refine")


def test_the_rigs_photos_divide_the_surface_out_of_every_captured_image(pairs, tiny_ckpt, tmp_path, one_line_error):
    img0, img1 = pairs[0]
    lift = img1.astype(np.int16)
    white, black = np.clip(lift + 60, 0, 255).astype(np.uint8), (lift // 3).astype(np.uint8)
    w, b = _write(tmp_path / "white.png", white), _write(tmp_path / "black.png", black)
    for name in ("one", "two"):  # folder mode: one pair of photos for every pair (a fixed rig)
        _write(tmp_path / "P" / f"{name}.png", img0)
        _write(tmp_path / "C" / f"{name}.png", img1)
    folders = ("--projected", tmp_path / "P", "--captured", tmp_path / "C", "--model", tiny_ckpt)
    registrar = Registrar(tiny_ckpt, device="cpu")
    levels = (0, 64, 128, 191, 255)
    points = np.tile((np.array(levels) / 255) ** 2.6, (3, 1))
    measured = Response(1.8, projector_curve(levels, points), True, (1.7, 1.9), levels, points, 1.0, 100)
    (tmp_path / "r.json").write_text(json.dumps(response_record(measured)))
    for k, (photos, said) in enumerate(
        (
            (("--white", w, "--black", b), "white and black, gamma 2.2"),
            (("--white", w), "white alone (ambient light kept), gamma 2.2"),
            (("--white", w, "--black", b, "--response", tmp_path / "r.json"), "white and black, measured response"),
        )
    ):
        out = tmp_path / f"run{k}"
        result = _cli(*folders, "--out", out, *photos)
        assert result.exit_code == 0, (result.stderr, result.exception)
        kwargs = {
            "black": black if len(photos) >= 4 else None,
            "response": tmp_path / "r.json" if len(photos) == 6 else None,
        }
        expected = registrar.register(img0, img1, white=white, **kwargs)
        for name in ("one", "two"):
            flow, valid, header = read_flow_exr(out / f"{name}_flow.exr")
            assert header["photos"] == said
            np.testing.assert_allclose(flow, expected.flow, atol=1e-4)
            np.testing.assert_array_equal(valid, expected.claimed)
    files = ("--projected", tmp_path / "P" / "one.png", "--captured", tmp_path / "C" / "one.png", "--model", tiny_ckpt)
    one_line_error(_cli(*files, "--out", tmp_path / "f.exr", "--black", b), "--black needs --white")
    one_line_error(
        _cli(*files, "--out", tmp_path / "f.exr", "--response", tmp_path / "r.json"), "--response needs --white"
    )
    small = _write(tmp_path / "small.png", white[::2, ::2])
    one_line_error(_cli(*folders, "--out", tmp_path / "o", "--white", small), f"--white {small} is 48x32 px", "96x64")
    one_line_error(_cli(*files, "--out", tmp_path / "f.exr", "--white", b, "--black", w), "swapped")
    picture = _write(tmp_path / "V" / "one_flow.png", white)  # a photo where --viz would write a picture
    one_line_error(
        _cli(*folders, "--out", tmp_path / "o", "--viz", tmp_path / "V", "--white", picture), "--viz", "--white"
    )
    assert not (tmp_path / "o").exists() and not (tmp_path / "f.exr").exists()


def test_track_mode_divides_every_frame_by_the_same_photos(tiny_sequences, tiny_ckpt, tmp_path):
    reader = ShardReader(tiny_sequences)
    try:
        frames = [reader.read(k) for k in range(2)]
    finally:
        reader.close()
    for s in frames:
        _write(tmp_path / "P" / f"{s['params']['frame']:02d}.png", s["projected"])
        _write(tmp_path / "C" / f"{s['params']['frame']:02d}.png", s["captured"])
    lift = frames[0]["captured"].astype(np.int16)
    white, black = np.clip(lift + 60, 0, 255).astype(np.uint8), (lift // 3).astype(np.uint8)
    photos = ("--white", _write(tmp_path / "w.png", white), "--black", _write(tmp_path / "b.png", black))
    out = tmp_path / "out"
    result = _cli(
        "--projected",
        tmp_path / "P",
        "--captured",
        tmp_path / "C",
        "--out",
        out,
        "--model",
        tiny_ckpt,
        "--track",
        *photos,
    )
    assert result.exit_code == 0, (result.stderr, result.exception)
    headers = [read_flow_exr(out / f"{i:02d}_flow.exr")[2] for i in range(2)]
    assert [h["photos"] for h in headers] == ["white and black, gamma 2.2"] * 2 and headers[0]["tracking"] == "full"
    first = Registrar(tiny_ckpt, device="cpu").register(
        frames[0]["projected"], frames[0]["captured"], white=white, black=black
    )
    np.testing.assert_allclose(read_flow_exr(out / "00_flow.exr")[0], first.flow, atol=1e-4)


def _frames_as_folders_and_videos(tiny_sequences, tmp_path, count=3):
    """One sequence's frames written as two folders of PNGs and two lossless (FFV1) videos."""
    from projreg.inference.video import VideoWriter

    reader = ShardReader(tiny_sequences)
    try:
        frames = [reader.read(k) for k in range(count)]
    finally:
        reader.close()
    for side in ("projected", "captured"):
        with VideoWriter(tmp_path / f"{side}.mkv", 30.0) as video:
            for s in frames:
                _write(tmp_path / side / f"{s['params']['frame']:02d}.png", s[side])
                video.write(s[side])
    return frames


def test_track_on_lossless_videos_gives_the_flows_of_the_folders_of_their_frames(tiny_sequences, tiny_ckpt, tmp_path):
    _frames_as_folders_and_videos(tiny_sequences, tmp_path)
    for track in (["--track"], []):
        outs = {}
        for kind, p, c in (
            ("folders", tmp_path / "projected", tmp_path / "captured"),
            ("videos", tmp_path / "projected.mkv", tmp_path / "captured.mkv"),
            ("mixed", tmp_path / "projected", tmp_path / "captured.mkv"),
        ):
            out = outs[kind] = tmp_path / f"out-{kind}{'-track' * bool(track)}"
            result = _cli(
                "--projected", p, "--captured", c, "--out", out, "--model", tiny_ckpt, "--quality", "fast", *track
            )
            assert result.exit_code == 0, (result.stderr, result.exception)
        folders = sorted(outs["folders"].glob("*.exr"))
        for kind in ("videos", "mixed"):
            videos = sorted(outs[kind].glob("*.exr"))
            assert [p.name for p in videos] == ["000000_flow.exr", "000001_flow.exr", "000002_flow.exr"]
            for a, b in zip(folders, videos, strict=True):
                (fa, va, ha), (fb, vb, hb) = read_flow_exr(a), read_flow_exr(b)
                np.testing.assert_array_equal(fa, fb)
                np.testing.assert_array_equal(va, vb)
                assert ha.get("tracking") == hb.get("tracking") and hb["sample_id"].startswith("captured.mkv#0000")


def test_a_still_projected_image_pairs_with_every_captured_frame(tiny_sequences, tiny_ckpt, tmp_path):
    frames = _frames_as_folders_and_videos(tiny_sequences, tmp_path, count=2)
    still = _write(tmp_path / "content.png", frames[0]["projected"])  # the content stays fixed over a sequence
    out = tmp_path / "out"
    result = _cli("--projected", still, "--captured", tmp_path / "captured.mkv", "--out", out, "--model", tiny_ckpt)
    assert result.exit_code == 0, (result.stderr, result.exception)
    registrar = Registrar(tiny_ckpt, device="cpu")
    for k, s in enumerate(frames):
        flow, valid, _ = read_flow_exr(out / f"{k:06d}_flow.exr")
        expected = registrar.register(frames[0]["projected"], s["captured"])
        np.testing.assert_allclose(flow, expected.flow, atol=1e-4)


def test_videos_that_do_not_pair_are_one_line_and_nothing_is_written(
    tiny_sequences, tiny_ckpt, tmp_path, one_line_error
):
    from projreg.inference.video import VideoWriter

    frames = _frames_as_folders_and_videos(tiny_sequences, tmp_path)
    with VideoWriter(tmp_path / "short.mkv", 30.0) as video:
        for s in frames[:2]:
            video.write(s["captured"])
    out = tmp_path / "out"
    args = ("--out", out, "--model", tiny_ckpt, "--track")
    one_line_error(
        _cli("--projected", tmp_path / "projected.mkv", "--captured", tmp_path / "short.mkv", *args),
        "--projected",
        "has 3 frames but --captured",
        "has 2",
        "nothing was written",
    )
    cut = tmp_path / "cut.mkv"
    cut.write_bytes((tmp_path / "captured.mkv").read_bytes()[:-400])
    one_line_error(
        _cli("--projected", tmp_path / "projected.mkv", "--captured", cut, *args), "--captured", "cannot be read"
    )
    cv2.imwrite(str(tmp_path / "captured" / "02.png"), np.zeros((48, 96, 3), np.uint8))  # the camera changed size
    one_line_error(
        _cli("--projected", tmp_path / "projected.mkv", "--captured", tmp_path / "captured", *args),
        "--captured",
        "02.png is 96x48 px",
        "nothing was written",
    )
    assert not out.exists()
