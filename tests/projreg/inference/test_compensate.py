import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from projreg.cli import app
from projreg.inference.compensate import compensate
from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import encode_flow_exr, write_flow_exr
from projsynth.sim.photometric import PAPER_IDENTITY
from projsynth.sim.render import render
from projsynth.sim.rig import make_scene
from projsynth.sim.scene import backward, pixel_grid

H, W = 96, 128


def _texture(seed):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (H, W, 3)).astype(np.float32), (0, 0), 2.0)
    return np.clip((tex - tex.min()) / (tex.max() - tex.min()) * 255, 0, 255).astype(np.uint8)


def test_projecting_the_prewarped_image_shows_the_content():
    cfg = next(c for c in builtin_table().configs if c.family == "sphere_convex" and c.severity == 3)
    scene, _ = make_scene(cfg.family, cfg.geometry, np.random.default_rng(4), (H, W))
    content = _texture(1)
    gt = render(content, np.zeros_like(content), scene, PAPER_IDENTITY, "paper", np.random.default_rng(0))
    prewarped = compensate(content, gt.flow, gt.valid)
    seen = render(prewarped, np.zeros_like(content), scene, PAPER_IDENTITY, "paper", np.random.default_rng(0)).captured
    naive = gt.captured  # projecting the content itself
    # camera pixels lit from well inside the valid projector region
    xy, lit = backward(scene, pixel_grid(H, W))
    inner = cv2.erode(gt.valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    px, py = np.clip(np.round(xy), 0, [[W - 1], [H - 1]]).astype(int)
    mask = (lit & inner[py, px]).reshape(H, W)
    assert mask.sum() > 2000
    err = np.abs(seen.astype(float) - content)[mask].mean()
    err_naive = np.abs(naive.astype(float) - content)[mask].mean()
    assert err < 4.0 and err < 0.2 * err_naive, (err, err_naive)


def compensate_cli(content, out):
    """``projreg compensate`` of ``content`` through the test's flow (``f.exr`` beside it) into ``out``."""
    return CliRunner().invoke(
        app, ["compensate", "--content", str(content), "--flow", str(content.parent / "f.exr"), "--out", str(out)]
    )


def test_cli_writes_the_projector_image(tmp_path):
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 2.0
    valid = np.ones((H, W), bool)
    valid[:, -2:] = False
    write_flow_exr(tmp_path / "f.exr", flow, valid, "x")
    content = _texture(2)
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(content, cv2.COLOR_RGB2BGR))
    result = compensate_cli(tmp_path / "c.png", tmp_path / "p.png")
    assert result.exit_code == 0, result.stderr
    lit = f"{(W - 2) / W:.1%}"  # the one-line summary on success
    assert (
        result.stderr == f"{tmp_path / 'p.png'}: {W}x{H} projector image (geometric), content on {lit} of its "
        "pixels, --fill 0 elsewhere\n"
    )
    out = cv2.cvtColor(cv2.imread(str(tmp_path / "p.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(out[:, :-2], content[:, 2:])  # p shows content at p + (2, 0)
    assert (out[:, -2:] == 0).all()
    bad = compensate_cli(tmp_path / "nope.png", tmp_path / "p.png")
    assert bad.exit_code == 2 and "nope.png" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    jpg = compensate_cli(tmp_path / "c.png", tmp_path / "p.jpg")
    assert jpg.exit_code == 2 and "--out" in jpg.stderr and "ending in .png" in jpg.stderr
    assert not (tmp_path / "p.jpg").exists()


def _flow_file(path, registered="yes", confidence=True):
    """A flow EXR as `projreg predict` writes one: a shift of (3, 1) px, claimed on the left half, the
    confidence falling from 1 to 0 across the frame."""
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0], flow[..., 1] = 3.0, 1.0
    claimed = np.zeros((H, W), bool)
    claimed[:, : W // 2] = registered == "yes"
    conf = np.tile(np.linspace(1, 0, W, dtype=np.float32), (H, 1))
    attrs = {"registered": registered, "camera_size": f"{H}x{W}", "valid_threshold": "confidence >= 0.5"}
    data = encode_flow_exr(flow, claimed, "x", attrs=attrs, confidence=conf if confidence else None)
    path.write_bytes(data)
    return flow, conf


def _run(tmp_path, *args):
    content = _texture(5)
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(content, cv2.COLOR_RGB2BGR))
    out = tmp_path / f"p{len(list(tmp_path.glob('p*.png')))}.png"
    result = CliRunner().invoke(
        app,
        [
            "compensate",
            "--content",
            str(tmp_path / "c.png"),
            "--flow",
            str(tmp_path / "f.exr"),
            "--out",
            str(out),
            *args,
        ],
    )
    image = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB) if out.exists() else None
    return result, image, content


def test_the_default_shows_content_on_every_pixel_that_lands_in_the_frame_claimed_or_not(tmp_path):
    _flow_file(tmp_path / "f.exr")
    result, out, content = _run(tmp_path)
    assert result.exit_code == 0, result.stderr
    np.testing.assert_array_equal(out[: H - 1, : W - 3], content[1:, 3:])  # p shows the content at p + (3, 1)
    assert (out[:, W - 3 :] == 0).all() and (out[H - 1] == 0).all()  # lands outside the frame: --fill
    assert f"content on {(H - 1) * (W - 3) / (H * W):.1%} of its pixels" in result.stderr
    claimed_only, out, _ = _run(tmp_path, "--coverage", "claimed")
    assert claimed_only.exit_code == 0, claimed_only.stderr
    assert (out[:, W // 2 :] == 0).all() and (out[: H - 1, : W // 2] == content[1:, 3 : W // 2 + 3]).all()
    confident, out, _ = _run(tmp_path, "--min-confidence", "0.75")
    assert confident.exit_code == 0, confident.stderr
    shown = np.tile(np.linspace(1, 0, W) >= 0.75, (H, 1))
    shown[H - 1] = False
    assert ((out != 0).any(axis=2) <= shown).all() and (out[shown] == content[1:, 3:][shown[: H - 1, : W - 3]]).all()


def test_a_pair_that_did_not_register_is_projected_as_it_is(tmp_path):
    _flow_file(tmp_path / "f.exr", registered="no")
    result, out, content = _run(tmp_path)
    assert result.exit_code == 0, result.stderr
    np.testing.assert_array_equal(out, content)
    assert "not registered; the content is projected as it is" in result.stderr and "(uncompensated)" in result.stderr
    claimed, _, _ = _run(tmp_path, "--coverage", "claimed")  # claims nothing: nothing to show
    assert claimed.exit_code == 2 and "nothing to compensate" in claimed.stderr


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--coverage", "verified"], "--coverage must be one of complete, claimed"),
        (["--min-confidence", "1.5"], "--min-confidence: expected a number in [0, 1], got 1.5"),
    ],
)
def test_bad_coverage_options_are_one_line_and_write_nothing(tmp_path, args, says):
    _flow_file(tmp_path / "f.exr")
    result, out, _ = _run(tmp_path, *args)
    assert result.exit_code == 2 and says in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert out is None


def test_a_confidence_threshold_needs_a_flow_that_carries_one(tmp_path):
    _flow_file(tmp_path / "f.exr", confidence=False)  # an older predict, or another tool
    result, out, _ = _run(tmp_path, "--min-confidence", "0.5")
    assert result.exit_code == 2 and "carries no per-pixel confidence" in result.stderr and out is None
    assert _run(tmp_path)[0].exit_code == 0  # the default needs none


def test_content_of_another_aspect_is_refused(tmp_path):
    _flow_file(tmp_path / "f.exr")
    wide = np.zeros((H, 2 * W, 3), np.uint8)
    cv2.imwrite(str(tmp_path / "wide.png"), wide)
    result = CliRunner().invoke(
        app,
        [
            "compensate",
            "--content",
            str(tmp_path / "wide.png"),
            "--flow",
            str(tmp_path / "f.exr"),
            "--out",
            str(tmp_path / "o.png"),
        ],
    )
    assert result.exit_code == 2 and "would be stretched" in result.stderr and not (tmp_path / "o.png").exists()


def test_a_ground_truth_flow_is_used_where_its_valid_says(tmp_path):
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 2.0
    valid = np.ones((H, W), bool)
    valid[20:40, 30:60] = False  # projsynth stores 0 there: not a flow to show content by
    flow[~valid] = 0
    write_flow_exr(tmp_path / "f.exr", flow, valid, "gt")
    result, out, content = _run(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert (out[20:40, 30:60] == 0).all()
    np.testing.assert_array_equal(out[:20, : W - 2], content[:20, 2:])


def _shift_exr(path, dx, registered="yes"):
    """A flow EXR as `projreg predict` writes one: a shift of (dx, 0) px claimed everywhere."""
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = dx
    attrs = {"registered": registered, "camera_size": f"{H}x{W}", "valid_threshold": "confidence >= 0.5"}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode_flow_exr(flow, np.ones((H, W), bool), "x", attrs=attrs))


def _cli(*args):
    return CliRunner().invoke(app, ["compensate", *(str(a) for a in args)])


def test_a_content_video_and_a_sequences_flows_give_the_projectors_video_frame_by_frame(tmp_path):
    from projreg.inference.video import VideoFile, VideoWriter

    frames = [_texture(10 + k) for k in range(3)]
    with VideoWriter(tmp_path / "content.mkv", 24.0) as video:
        for k, frame in enumerate(frames):
            video.write(frame)
            _shift_exr(tmp_path / "flows" / f"{k:06d}_flow.exr", 1.0 + k, "no" if k == 2 else "yes")
            cv2.imwrite(str(tmp_path / f"c{k}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    result = _cli("--content", tmp_path / "content.mkv", "--flow", tmp_path / "flows", "--out", tmp_path / "p.mkv")
    assert result.exit_code == 0, result.stderr
    assert (
        "1 of 3 frames' pairs were not registered" in result.stderr and "projector video of 3 frames" in result.stderr
    )
    shown = list(VideoFile(tmp_path / "p.mkv", "--out"))
    assert VideoFile(tmp_path / "p.mkv", "--out").fps == 24.0  # the content's rate
    for k, frame in enumerate(shown):  # each frame is what compensate writes for its content and flow
        flow = tmp_path / "flows" / f"{k:06d}_flow.exr"
        assert _cli("--content", tmp_path / f"c{k}.png", "--flow", flow, "--out", tmp_path / f"p{k}.png").exit_code == 0
        np.testing.assert_array_equal(frame, cv2.cvtColor(cv2.imread(str(tmp_path / f"p{k}.png")), cv2.COLOR_BGR2RGB))
    # a still content on a moving rig, at --fps; a content video on a fixed rig (one flow)
    still = _cli(
        "--content", tmp_path / "c0.png", "--flow", tmp_path / "flows", "--out", tmp_path / "s.mkv", "--fps", 10
    )
    assert still.exit_code == 0, still.stderr
    video = VideoFile(tmp_path / "s.mkv", "--out")
    assert len(list(video)) == 3 and video.fps == 10
    one = tmp_path / "flows" / "000000_flow.exr"
    assert _cli("--content", tmp_path / "content.mkv", "--flow", one, "--out", tmp_path / "f.mkv").exit_code == 0
    assert len(list(VideoFile(tmp_path / "f.mkv", "--out"))) == 3


def test_a_content_video_and_flows_that_do_not_pair_are_one_line_and_write_nothing(tmp_path, one_line_error):
    from projreg.inference.video import VideoWriter

    with VideoWriter(tmp_path / "content.mkv", 30.0) as video:
        for k in range(3):
            video.write(_texture(k))
    for k in range(2):
        _shift_exr(tmp_path / "flows" / f"{k:06d}_flow.exr", 1.0)
    content, flows = tmp_path / "content.mkv", tmp_path / "flows"
    args = ("--content", content, "--flow", flows, "--out")
    one_line_error(_cli(*args, tmp_path / "p.mkv"), "--content", "has 3 frames but --flow", "holds 2 flow EXRs")
    one_line_error(_cli(*args, tmp_path / "p.png"), "--out", "a video is written as .mkv (FFV1)")
    _shift_exr(tmp_path / "flows" / "000002_flow.exr", 1.0)
    (tmp_path / "flows" / "000002_flow.exr").write_bytes(b"not an exr")  # a flow that does not read, last
    one_line_error(_cli(*args, tmp_path / "p.mkv"), "000002_flow.exr")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["content.mkv", "flows"]  # no video, no temporary


def test_a_frame_rate_out_of_range_or_for_a_picture_and_an_empty_content_are_one_line(tmp_path, one_line_error):
    from projreg.inference.video import VideoWriter

    with VideoWriter(tmp_path / "content.mkv", 30.0) as video:
        video.write(_texture(0))
    _shift_exr(tmp_path / "f.exr", 1.0)
    cv2.imwrite(str(tmp_path / "c.png"), _texture(1))
    (tmp_path / "afile").write_text("a file where a folder would be")
    video = ("--content", tmp_path / "content.mkv", "--flow", tmp_path / "f.exr", "--out", tmp_path / "p.mkv")
    for fps in ("inf", "1e12", "0"):  # inf hung in FFmpeg; 1e12 blamed --out
        one_line_error(_cli(*video, "--fps", fps), "--fps: expected a number in (0, 1000]")
    picture = ("--content", tmp_path / "c.png", "--flow", tmp_path / "f.exr", "--out", tmp_path / "p.png")
    one_line_error(_cli(*picture, "--fps", "30"), "--fps sets the frame rate of a video", "drop --fps")  # was ignored
    empty = _cli("--content", "", *picture[2:])  # was read as the current folder, and --out blamed
    assert empty.exit_code == 2 and "Invalid value for '--content': empty" in empty.stderr  # a usage error
    under_file = ("--content", tmp_path / "content.mkv", "--flow", tmp_path / "f.exr", "--out")
    one_line_error(_cli(*under_file, tmp_path / "afile" / "p.mkv"), "--out", "afile is a file, not a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "c.png", "content.mkv", "f.exr"]
