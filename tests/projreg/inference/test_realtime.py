"""Frames by the clock: a played video hands over its newest frame and passes the rest (which frame
depends on the clock alone: a fake clock makes it exact); a camera read by a thread keeps only its
newest frame; content on show plays at its rate and loops."""

import cv2
import numpy as np
import pytest

from projreg import ProjregError
from projreg.inference.realtime import Content, DeviceCamera, PlayedVideo
from projreg.inference.video import VideoWriter


class FakeClock:
    """Time that moves only when slept (or when a test moves it)."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, dt):
        self.t += max(dt, 0.0)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (16, 24, 3), dtype=np.uint8) for _ in range(10)]
    path = tmp_path_factory.mktemp("v") / "ten.mkv"
    with VideoWriter(path, 10.0) as w:
        for frame in frames:
            w.write(frame)
    return path, frames


def test_a_played_video_hands_over_the_newest_frame_by_the_clock(video):
    path, frames = video
    clock = FakeClock()
    camera = PlayedVideo(path, clock=clock, sleep=clock.sleep)
    assert camera.start() == 100.0 and camera.fps == 10.0
    taken = [camera.take()]  # frame 0 at once
    clock.t += 0.35  # frames 1, 2, 3 arrive meanwhile: 3 is the newest
    taken.append(camera.take())
    taken.append(camera.take())  # the loop is ahead: it waits for frame 4
    assert [s.index for s in taken] == [0, 3, 4] and clock.t == pytest.approx(100.4)
    assert [s.arrival for s in taken] == pytest.approx([100.0, 100.3, 100.4])
    for shot in taken:
        np.testing.assert_array_equal(shot.image, frames[shot.index])
    clock.t += 60.0  # long past the end: the last frame, then nothing
    assert camera.take().index == 9 and camera.take() is None
    assert camera.arrived(clock.t) == 10
    camera.close()


def test_a_camera_read_by_a_thread_keeps_only_its_newest_frame(video):
    path, frames = video
    camera = DeviceCamera(cv2.VideoCapture(str(path)))  # a stream read as fast as it decodes
    camera.start()
    shots = []
    while (shot := camera.take()) is not None:
        shots.append(shot)
        np.testing.assert_array_equal(shot.image, frames[shot.index])
    camera.close()
    indices = [s.index for s in shots]
    assert indices == sorted(set(indices)) and indices[-1] <= 9 and camera.arrived(0.0) == 10
    with pytest.raises(ProjregError, match="--captured 97: OpenCV cannot open camera 97"):
        DeviceCamera(97)


def test_content_on_show_is_the_video_frame_of_the_moment_and_loops(video, tmp_path):
    path, frames = video
    content = Content(path)
    content.start(50.0)
    for t, k in ((50.0, 0), (50.25, 2), (50.99, 9), (51.05, 0), (51.31, 3)):
        image, index = content.at(t)
        assert index == k
        np.testing.assert_array_equal(image, frames[k])
    content.close()
    still = Content(frames[4])
    assert still.at(1e6)[1] == 0 and still.at(0)[0] is frames[4]


@pytest.mark.parametrize("index", [-1, 10_000, 99_999_999_999])
def test_a_camera_index_out_of_range_is_refused_before_opencv_sees_it(index):
    with pytest.raises(ProjregError, match=rf"^--captured {index}: a camera index is in 0..9999"):
        DeviceCamera(index)  # -1 crashed OpenCV, 10**11 overflowed it


def test_probing_a_missing_camera_prints_nothing(capfd):
    with pytest.raises(ProjregError, match="OpenCV cannot open camera 97"):
        DeviceCamera(97)
    assert capfd.readouterr().err == ""  # OpenCV's own [ WARN ] lines are silenced while it probes


@pytest.mark.parametrize("fps", [-5, 0, float("nan"), float("inf"), "30", True])
def test_a_frame_rate_out_of_range_is_refused_when_the_video_is_given(video, fps):
    path, frames = video
    with pytest.raises(ProjregError, match=r"^fps: expected a number in \(0, 1000\]"):
        PlayedVideo(path, fps=fps)
    with pytest.raises(ProjregError, match=r"^fps: expected a number in \(0, 1000\]"):
        Content(path, fps=fps)


def test_none_is_the_videos_own_rate_and_a_content_image_is_checked(video):
    path, frames = video
    assert PlayedVideo(path).fps == Content(path).fps == 10.0 and PlayedVideo(path, fps=np.float32(5)).fps == 5.0
    with pytest.raises(ProjregError, match=r"^content: expected a uint8 RGB array \(H, W, 3\), got float32"):
        Content(frames[0].astype(np.float32), "content")
    with pytest.raises(ProjregError, match="^fps: --content is a still image"):
        Content(frames[0], fps=5)
    with pytest.raises(ProjregError, match="^--content: empty"):
        Content("")


def test_a_truncated_content_video_is_refused_when_the_show_reaches_it(video, tmp_path):
    path, frames = video
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    content = Content(cut)
    content.start(0.0)
    assert content.at(0.0)[1] == 0
    with pytest.raises(ProjregError, match=r"^--content .*cut.mkv: frame \d+ cannot be read of the 10 its container"):
        content.at(0.95)  # frame 9: past what reads; it looped over the readable frames before
    content.close()
