"""The live loop on a moving rig's sequence played as a camera: frames in = registered + dropped, each
registered frame is tracked from the previous one and its pre-warp is compensate's; motion prediction
carries the flow forward at constant velocity; Ctrl-C keeps what was written, an error writes nothing.
Counts and invariants are asserted on a fake clock, never the machine's speed."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.api import Registrar
from projreg.cli import app
from projreg.inference.compensate import prewarp
from projreg.inference.live import Live, extrapolate, record_live
from projreg.inference.pipeline import Pipeline
from projreg.inference.realtime import Content, PlayedVideo, Shot
from projreg.inference.video import VideoFile, VideoWriter
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import resolve_plan
from projsynth.dataset.shards import ShardReader

FRAMES = 8  # a short orbit: the rig moves a little every frame


class FakeClock:
    """Time that moves by ``cost`` on every reading (the loop's work) and when slept."""

    def __init__(self, cost=0.0):
        self.t, self.cost = 0.0, cost

    def __call__(self):
        self.t += self.cost
        return self.t

    def sleep(self, dt):
        self.t += max(dt, 0.0)


@pytest.fixture(scope="module")
def orbit(tmp_path_factory):
    """One orbiting sequence's camera frames as a 30 fps FFV1 video, and the still content shown."""
    plan = resolve_plan(
        size=(64, 96), seed=5, split="test", pairs=1, transforms="0", blend="paper", frames=FRAMES, motion="orbit"
    )
    root = tmp_path_factory.mktemp("orbit")
    generate(plan, root / "data", shard_size=FRAMES)
    reader = ShardReader(root / "data")
    try:
        samples = [reader.read(k) for k in range(FRAMES)]
    finally:
        reader.close()
    with VideoWriter(root / "camera.mkv", 30.0) as video:
        for s in samples:
            video.write(s["captured"])
    return root / "camera.mkv", samples[0]["projected"], samples


@pytest.fixture(scope="module")
def pipeline(tiny_ckpt):
    return Pipeline(tiny_ckpt, quality="fast", device="cpu")


def _loop(pipeline, orbit, cost, **options):
    clock = FakeClock(cost)
    camera = PlayedVideo(orbit[0], clock=clock, sleep=clock.sleep)
    return Live(pipeline, camera, Content(orbit[1]), **options)


def test_extrapolate_carries_a_constant_velocity_forward():
    a = np.random.default_rng(0).normal(size=(4, 5, 2)).astype(np.float32)
    v = np.float32(0.25)
    # registered at camera frames 4 and 7; shown 2.5 frames after frame 7: the flow of frame 9.5
    np.testing.assert_allclose(extrapolate(a + 7 * v, a + 4 * v, 3, 2.5), a + 9.5 * v, atol=1e-6)


def test_a_loop_faster_than_the_camera_registers_every_frame(pipeline, orbit):
    live = _loop(pipeline, orbit, cost=0.0)  # the work takes no time on this clock
    frames = list(live)
    assert [f.index for f in frames] == list(range(FRAMES))
    assert [f.registration.step for f in frames][0] == "full"
    summary = live.summary()
    assert (summary["frames_in"], summary["registered"], summary["dropped"]) == (FRAMES, FRAMES, 0)
    for f in frames:  # the pre-warp is compensate's, with the registration's own flow
        assert f.horizon == 0 and f.latency_ms == 0 and f.flow is f.registration.flow
        reg = f.registration
        expected = prewarp(
            orbit[1],
            reg.flow,
            claimed=reg.claimed,
            confidence=reg.confidence,
            registered=reg.registered,
            camera_size=reg.camera_size,
        )
        np.testing.assert_array_equal(f.projector, expected)


def test_a_slow_loop_drops_frames_and_counts_them(pipeline, orbit):
    live = _loop(pipeline, orbit, cost=0.02)  # every clock reading costs 20 ms: frames pile up meanwhile
    frames = list(live)
    summary = live.summary()
    indices = [f.index for f in frames]
    assert indices == sorted(set(indices)) and summary["dropped"] > 0
    assert summary["frames_in"] == FRAMES == summary["registered"] + summary["dropped"]
    assert [f.dropped for f in frames] == [k - n for n, k in enumerate(indices)]  # dropped before each
    assert all(f.latency_ms > 0 for f in frames) and summary["latency_ms"]["p95"] >= summary["latency_ms"]["median"]
    assert summary["fps"] == pytest.approx(len(frames) / summary["seconds"])


def test_motion_prediction_carries_each_flow_forward_by_its_latency(pipeline, orbit):
    live = _loop(pipeline, orbit, cost=0.01, predict_motion=True)
    frames = list(live)
    assert frames[0].horizon == 0  # one registration: no velocity yet
    carried = 0
    for before, f in zip(frames, frames[1:], strict=False):
        if before.registration.step == f.registration.step == "tracked" and f.registration.registered:
            assert f.horizon > 0
            expected = extrapolate(f.registration.flow, before.registration.flow, f.index - before.index, f.horizon)
            np.testing.assert_array_equal(f.flow, expected)
            carried += 1
        else:  # after a full registration (the first, a lost track): its jump is no motion
            assert f.horizon == 0 and f.flow is f.registration.flow
    assert carried == sum(r["horizon_frames"] > 0 for r in live.records()) >= 1, [f.registration.step for f in frames]


def test_ctrl_c_stops_cleanly_and_keeps_what_was_written(pipeline, orbit, tmp_path):
    live = _loop(pipeline, orbit, cost=0.0)
    take = live.camera.take

    def interrupted():
        shot = take()
        if shot is not None and shot.index == 3:
            raise KeyboardInterrupt
        return shot

    live.camera.take = interrupted
    summary = record_live(live, tmp_path / "out.mkv", tmp_path / "stats.json")
    assert summary["interrupted"] and summary["registered"] == 3
    assert len(list(VideoFile(tmp_path / "out.mkv", "--out"))) == 3
    report = json.loads((tmp_path / "stats.json").read_text())
    assert report["summary"]["registered"] == 3 and [r["index"] for r in report["frames"]] == [0, 1, 2]


class ListCamera:
    """A camera handing over a list's frames one after the other, on a fake clock."""

    fps = 30.0

    def __init__(self, frames):
        self.frames, self.clock, self.given = frames, FakeClock(), 0

    def start(self):
        return self.clock()

    def take(self):
        if self.given == len(self.frames):
            return None
        self.given += 1
        return Shot(self.given - 1, self.frames[self.given - 1], self.clock())

    def arrived(self, now):
        return self.given

    def close(self):
        pass


def test_a_camera_that_changes_size_is_one_error_and_nothing_is_written(pipeline, orbit, tmp_path):
    frames = [s["captured"] for s in orbit[2][:4]]
    frames[2] = frames[2][:48]  # a camera replugged in another mode
    live = Live(pipeline, ListCamera(frames), Content(orbit[1]))
    with pytest.raises(ProjregError, match=r"camera frames\[2\]: frame sizes changed within the sequence"):
        record_live(live, tmp_path / "out.mkv", tmp_path / "stats.json")
    assert list(tmp_path.iterdir()) == []


def test_the_api_and_the_command_run_the_loop(tiny_ckpt, orbit, tmp_path, one_line_error):
    registrar = Registrar(tiny_ckpt, quality="fast", device="cpu")
    live = registrar.live(orbit[0], orbit[1], limit=2)
    assert 1 <= len(list(live)) <= 2 and live.summary()["frames_in"] >= 1
    still = tmp_path / "still.png"
    import cv2

    cv2.imwrite(str(still), orbit[1][..., ::-1])
    args = ["live", "--captured", str(orbit[0]), "--content", str(still), "--model", str(tiny_ckpt), "-q"]
    result = CliRunner().invoke(
        app, [*args, "--frames", "2", "--out", str(tmp_path / "o.mkv"), "--stats", str(tmp_path / "s.json")]
    )
    assert result.exit_code == 0, (result.stderr, result.exception)
    report = json.loads((tmp_path / "s.json").read_text())["summary"]
    assert 1 <= report["registered"] <= 2 and report["frames_in"] == report["registered"] + report["dropped"]
    assert len(list(VideoFile(tmp_path / "o.mkv", "--out"))) == report["registered"]
    assert result.stderr.startswith(f"live: {report['frames_in']} frames in, {report['registered']} registered")
    one_line_error(CliRunner().invoke(app, [*args, "--stats", str(tmp_path / "s.txt")]), "--stats", ".json")
    missing = ["live", "--captured", str(tmp_path / "none.mkv"), "--content", str(still), "-q"]
    one_line_error(CliRunner().invoke(app, missing), "--captured", "none.mkv")
    with pytest.raises(ProjregError, match="limit"):
        registrar.live(orbit[0], orbit[1], limit=0)


def test_a_loop_runs_once(pipeline, orbit):
    live = _loop(pipeline, orbit, cost=0.0)
    live.limit = 1
    assert len(list(live)) == 1
    with pytest.raises(ProjregError, match="^the live loop runs once"):  # a second pass yielded nothing
        list(live)
    assert live.summary()["registered"] == 1


def test_a_truncated_content_video_stops_the_loop_as_predict_refuses_it(pipeline, orbit, tmp_path):
    content = tmp_path / "content.mkv"
    with VideoWriter(content, 30.0) as video:
        for s in orbit[2]:
            video.write(s["projected"])
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(content.read_bytes()[: content.stat().st_size // 2])
    clock = FakeClock(cost=0.05)  # the show moves on 1.5 content frames per clock reading
    live = Live(pipeline, PlayedVideo(orbit[0], clock=clock, sleep=clock.sleep), Content(cut))
    with pytest.raises(ProjregError, match=rf"^--content .*cut.mkv: frame \d+ cannot be read of the {FRAMES} its"):
        record_live(live, tmp_path / "out.mkv", tmp_path / "stats.json")  # it looped over the readable frames
    assert sorted(p.name for p in tmp_path.iterdir()) == ["content.mkv", "cut.mkv"]


def test_the_commands_bad_camera_and_output_are_one_line_before_the_loop(orbit, tmp_path, one_line_error):
    import cv2

    still = tmp_path / "still.png"
    cv2.imwrite(str(still), orbit[1][..., ::-1])
    (tmp_path / "afile").write_text("a file where a folder would be")
    base = ["live", "--content", str(still), "-q", "--frames", "1"]
    for captured, says in (("99999999999", "a camera index is in 0..9999"), ("", "--captured: empty")):
        one_line_error(CliRunner().invoke(app, [*base, "--captured", captured]), says)
    for option in ("--out", "--stats"):
        name = "o.mkv" if option == "--out" else "s.json"
        result = CliRunner().invoke(app, [*base, "--captured", str(orbit[0]), option, str(tmp_path / "afile" / name)])
        one_line_error(result, option, "afile is a file, not a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "still.png"]
