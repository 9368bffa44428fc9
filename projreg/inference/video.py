"""Video files, read and written with OpenCV's FFmpeg backend (opencv-python-headless bundles FFmpeg:
whatever its FFmpeg decodes reads; docs/design.md, "Dependencies").

A video is read as uint8 RGB frames ``(H, W, 3)`` in order (:class:`VideoFile`); a frame the container
states but the decoder cannot give (a damaged or truncated file) is an error, not the end of the
video. A video is written whole or not at all (:class:`VideoWriter`: a temporary name beside it, then a
rename); the codec follows the suffix (``VIDEO_CODECS``): ``.mkv`` is FFV1, lossless, so a video written
here and read back gives the very frames, bit for bit (``.avi``, HuffYUV, too).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

import cv2
import numpy as np

from ..checks import check_number
from ..errors import ProjregError
from .outputs import check_parent
from .register import check_image

VIDEO_SUFFIXES = (".mkv", ".mp4", ".avi", ".mov", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".wmv", ".flv")
# FFV1 in Matroska: lossless and compact; HuffYUV in AVI: lossless, large, 3-8x faster to encode and decode
# (the live loop's --out, a camera recording); MPEG-4 part 2 in MP4: lossy, for players without either
VIDEO_CODECS = {".mkv": "FFV1", ".avi": "HFYU", ".mp4": "mp4v"}
MAX_FPS = 1000.0  # frames per second: a high-speed camera's; beyond, FFmpeg's time base fails or an encoder hangs (inf)
FFMPEG_QUIET = "-8"  # AV_LOG_QUIET: the decoder's complaints about a damaged file become our one line


def is_video(path: Path) -> bool:
    """Whether ``path`` names a video file by its suffix (``VIDEO_SUFFIXES``), not a folder."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES and not Path(path).is_dir()


def check_video_suffix(path: Path, option: str) -> None:
    """Refuse a video name whose suffix has no codec here (``VIDEO_CODECS``), naming ``option``."""
    if Path(path).suffix.lower() not in VIDEO_CODECS:
        names = ", ".join(f"{s} ({c})" for s, c in VIDEO_CODECS.items())
        raise ProjregError(f"{option} {path}: a video is written as {names}; give one of these suffixes")


def check_fps(fps: object, name: str = "fps") -> float:
    """``fps`` as a float if it is a frame rate in (0, ``MAX_FPS``], else one line naming ``name``."""
    return check_number(name, fps, 0.0, MAX_FPS, low_open=True)


def quiet_opencv() -> int:
    """OpenCV's and FFmpeg's console messages off (an explicit ``OPENCV_FFMPEG_LOGLEVEL`` is kept); the
    previous OpenCV log level, to restore."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", FFMPEG_QUIET)
    return cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


class VideoFile:
    """A video file's frames, in order, as uint8 RGB ``(H, W, 3)``; ``option`` names it in errors.

    ``fps``: its frame rate (frames per second; None when the container states none); ``stated``: the
    number of frames its container states (None when it states none).

    Raises:
        ProjregError: the file is missing or OpenCV's FFmpeg cannot open it as a video.
    """

    def __init__(self, path: Path, option: str) -> None:
        self.path, self.option = Path(path), option
        if not self.path.is_file():
            raise ProjregError(f"{option} {self.path}: no such video file")
        capture = self.open()
        try:
            fps, count = capture.get(cv2.CAP_PROP_FPS), capture.get(cv2.CAP_PROP_FRAME_COUNT)
        finally:
            capture.release()
        self.fps = fps if fps > 0 else None
        self.stated = int(count) if count > 0 else None

    def open(self) -> cv2.VideoCapture:
        """A fresh ``cv2.VideoCapture`` of the file, at its first frame (the caller releases it)."""
        previous = quiet_opencv()
        try:
            capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        finally:
            cv2.utils.logging.setLogLevel(previous)
        if not capture.isOpened():
            raise ProjregError(
                f"{self.option} {self.path}: OpenCV's FFmpeg cannot read it as a video (damaged, or not a video)"
            )
        return capture

    def __iter__(self) -> Iterator[np.ndarray]:
        """The frames from the first, each read when asked for (a video is never held whole)."""
        capture, k = self.open(), 0
        try:
            while True:
                ok, bgr = capture.read()
                if not ok:
                    break
                k += 1
                yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        finally:
            capture.release()
        self.check_end(k)

    def check_end(self, k: int) -> None:
        """Refuse a video whose frame ``k`` did not read where its container states more frames (or none
        read at all): a damaged or truncated file, not the video's end."""
        if k == 0 or (self.stated is not None and k < self.stated):
            said = f" of the {self.stated} its container states" if self.stated else ""
            raise ProjregError(
                f"{self.option} {self.path}: frame {k} cannot be read{said}; the file is damaged or truncated"
            )


class VideoWriter:
    """A video written whole or not at all: frames go to a temporary file beside ``path`` (its suffix
    kept, for FFmpeg's container), renamed to ``path`` by :meth:`close`; leaving the ``with`` block by an
    exception (Ctrl-C included), or :meth:`discard`, removes it. A stopped run that should keep what was
    written calls :meth:`close`. The codec follows the suffix (``VIDEO_CODECS``); every frame is uint8
    RGB ``(H, W, 3)`` of the first one's size; ``fps`` a frame rate in (0, ``MAX_FPS``].

    Raises:
        ProjregError: naming ``option``: a suffix with no codec here, a folder of the path that is a
            file, or a file FFmpeg cannot write; ``fps`` out of range; a frame that is not uint8 RGB.
    """

    def __init__(self, path: Path, fps: float, option: str = "--out") -> None:
        self.path, self.fps, self.option = Path(path), check_fps(fps), option
        check_video_suffix(self.path, option)
        check_parent(self.path, option)
        self.tmp = self.path.with_name(f".{self.path.stem}.{secrets.token_hex(6)}.tmp{self.path.suffix}")
        self.codec = VIDEO_CODECS[self.path.suffix.lower()]
        self.writer: cv2.VideoWriter | None = None
        self.size: tuple[int, int] | None = None
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        """Append one uint8 RGB frame ``(H, W, 3)``."""
        check_image(f"{self.option} {self.path}: frame {self.frames}", rgb)
        if self.writer is None:
            self.size = rgb.shape[:2]
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise ProjregError(f"{self.option} {self.path}: cannot write ({e.strerror or e})") from e
            previous = quiet_opencv()
            try:
                fourcc = cv2.VideoWriter_fourcc(*self.codec)
                self.writer = cv2.VideoWriter(str(self.tmp), cv2.CAP_FFMPEG, fourcc, self.fps, self.size[::-1])
            finally:
                cv2.utils.logging.setLogLevel(previous)
            if not self.writer.isOpened():
                self.discard()
                raise ProjregError(f"{self.option} {self.path}: FFmpeg cannot write a {self.codec} video here")
        if rgb.shape[:2] != self.size:
            raise ProjregError(
                f"{self.option} {self.path}: frame {self.frames} is {rgb.shape[1]}x{rgb.shape[0]} px, the video "
                f"{self.size[1]}x{self.size[0]}"
            )
        self.writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> None:
        """Finish the file and rename it into place (no frame written: nothing is)."""
        if self.writer is None:
            return
        self.writer.release()
        self.writer = None
        try:
            with open(self.tmp, "rb") as f:
                os.fsync(f.fileno())
            os.replace(self.tmp, self.path)
        except OSError as e:
            self.tmp.unlink(missing_ok=True)
            raise ProjregError(f"{self.option} {self.path}: cannot write ({e.strerror or e})") from e

    def discard(self) -> None:
        """Drop what was written: the temporary file is removed, ``path`` untouched."""
        if self.writer is not None:
            self.writer.release()
            self.writer = None
        with contextlib.suppress(FileNotFoundError, NotADirectoryError):  # never written: nothing to remove
            self.tmp.unlink()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if kind is None:
            self.close()
        else:
            self.discard()
