"""Video files: FFV1 (.mkv) and HuffYUV (.avi) round-trip frames bit for bit; a damaged file, an unknown suffix and a
frame of another size are one line naming the option; a video is written whole or not at all; a folder,
a video and a still image are read as one side's frames."""

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from projreg import ProjregError
from projreg.inference.sources import Frames, paired_count, survey
from projreg.inference.video import VideoFile, VideoWriter, is_video


def write_video(path, frames, fps=30.0):
    with VideoWriter(path, fps) as writer:
        for frame in frames:
            writer.write(frame)
    return path


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16), count=st.integers(1, 4), h=st.integers(8, 40), w=st.integers(8, 40))
def test_a_lossless_video_gives_back_its_frames_bit_for_bit(tmp_path_factory, seed, count, h, w):
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 256, (2 * h, 2 * w, 3), dtype=np.uint8) for _ in range(count)]  # any content
    folder = tmp_path_factory.mktemp("v")
    for name in ("clip.mkv", "clip.avi"):  # FFV1, HuffYUV
        video = VideoFile(write_video(folder / name, frames, fps=25.0), "--captured")
        assert video.fps == 25.0 and is_video(folder / name)
        back = list(video)
        assert len(back) == count and all(np.array_equal(a, b) for a, b in zip(frames, back, strict=True))
    assert sorted(p.name for p in folder.iterdir()) == ["clip.avi", "clip.mkv"]  # no temporary left


def test_a_truncated_or_foreign_file_is_one_line_naming_the_option(tmp_path):
    rng = np.random.default_rng(0)
    path = write_video(tmp_path / "clip.mkv", [rng.integers(0, 256, (64, 96, 3), dtype=np.uint8) for _ in range(12)])
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ProjregError, match=r"--captured .*cut.mkv: frame \d+ cannot be read of the 12 its container"):
        list(VideoFile(cut, "--captured"))
    (tmp_path / "text.mp4").write_text("not a video")
    with pytest.raises(ProjregError, match="--content .*text.mp4: OpenCV's FFmpeg cannot read it as a video"):
        VideoFile(tmp_path / "text.mp4", "--content")
    with pytest.raises(ProjregError, match="--captured .*gone.mkv: no such video file"):
        VideoFile(tmp_path / "gone.mkv", "--captured")


def test_a_video_is_written_whole_or_not_at_all(tmp_path):
    frame = np.zeros((32, 48, 3), np.uint8)
    with pytest.raises(ProjregError, match=r"--out .*x.gif: a video is written as .mkv \(FFV1\)"):
        VideoWriter(tmp_path / "x.gif", 30)
    with (
        pytest.raises(ProjregError, match="frame 1 is 24x16 px, the video 48x32"),
        VideoWriter(tmp_path / "a.mkv", 30) as w,
    ):
        w.write(frame)
        w.write(frame[:16, :24])
    with pytest.raises(KeyboardInterrupt), VideoWriter(tmp_path / "b.mkv", 30) as w:
        w.write(frame)
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []  # neither the videos nor their temporaries
    stopped = VideoWriter(tmp_path / "c.avi", 30)  # HuffYUV
    stopped.write(frame)
    stopped.close()  # a stopped run keeps what it wrote
    assert len(list(VideoFile(tmp_path / "c.avi", "--out"))) == 1


def test_a_folder_a_video_and_a_still_image_are_one_sides_frames(tmp_path):
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (32, 48, 3), dtype=np.uint8) for _ in range(3)]
    (tmp_path / "d").mkdir()
    for k, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / "d" / f"{k}.png"), frame[..., ::-1])
    video = Frames(write_video(tmp_path / "v.mkv", frames), "--captured")
    folder, still = Frames(tmp_path / "d", "--captured"), Frames(tmp_path / "d" / "0.png", "--projected")
    assert (video.kind, folder.kind, still.kind) == ("video", "folder", "still") and not still.sequence
    for side in (video, folder):
        assert all(np.array_equal(a, b) for a, b in zip(side, frames, strict=True))
    assert survey(video) == [(32, 48, 3)] * 3 and survey(still) == [(32, 48, 3)]
    assert video.names(2) == ["000000", "000001"] and folder.names(3) == ["0.png", "1.png", "2.png"]
    assert paired_count(still, video, (1, 3)) == 3
    with pytest.raises(ProjregError, match="--projected .* has 3 frames but --captured .* has 2"):
        paired_count(folder, video, (3, 2))
    cv2.imwrite(str(tmp_path / "d" / "2.png"), np.zeros((16, 48, 3), np.uint8))
    with pytest.raises(ProjregError, match=r"--captured .*2.png is 48x16 px but .*0.png, the sequence's first"):
        survey(folder)
    assert len(survey(folder, check_size=False)) == 3


@pytest.mark.parametrize("fps", [float("inf"), float("nan"), None, 0, -5, 1e12, "30", True])
def test_a_frame_rate_out_of_range_is_refused_naming_fps(tmp_path, fps):
    with pytest.raises(ProjregError, match=r"^fps: expected a number in \(0, 1000\]"):  # inf hung in FFmpeg
        VideoWriter(tmp_path / "x.mkv", fps)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "frame",
    [
        np.zeros((32, 48, 3), np.float32),
        np.zeros((32, 48), np.uint8),  # grey
        np.zeros((32, 48, 4), np.uint8),  # RGBA
        np.zeros((32, 48, 3), np.uint8).tolist(),
    ],
)
def test_a_frame_that_is_not_uint8_rgb_is_refused_naming_it_and_nothing_is_written(tmp_path, frame):
    with (
        pytest.raises(ProjregError, match=r"^--out .*x.mkv: frame 0: expected a uint8 RGB"),
        VideoWriter(tmp_path / "x.mkv", np.float32(25)) as writer,
    ):
        writer.write(frame)
    assert list(tmp_path.iterdir()) == []


def test_a_video_under_a_file_is_refused_before_any_frame(tmp_path):
    (tmp_path / "afile").write_text("a file where a folder would be")
    with pytest.raises(ProjregError, match=r"^--out .*afile/x.mkv: cannot write \(.*afile is a file, not a folder\)"):
        VideoWriter(tmp_path / "afile" / "x.mkv", 30)
    writer = VideoWriter(tmp_path / "x.mkv", 30)
    writer.path, writer.tmp = tmp_path / "afile" / "x.mkv", tmp_path / "afile" / ".x.tmp.mkv"
    writer.discard()  # nothing was written under the file: nothing to remove, no error masking the first
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]
