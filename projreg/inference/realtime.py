"""Frames by the clock, for the live loop (:mod:`projreg.inference.live`): a camera, a video played as a
camera in real time, and the content on show.

A camera hands over its newest frame when asked (:meth:`PlayedVideo.take`, :meth:`DeviceCamera.take`):
a frame that arrived and was not taken before the next one arrived is dropped (counted by the loop:
frames in minus frames registered). At most one frame waits: never a queue. A camera's frame numbers
count every frame that arrived, taken or not, so the loop knows how many frames lie between two it
registered.

* :class:`PlayedVideo`: a video file as a camera: frame ``k`` becomes available at ``start + k / fps``
  on the clock (a fake real-time camera for tests and benchmarks: a clock and a sleep can be given);
* :class:`DeviceCamera`: an OpenCV camera (``cv2.VideoCapture(index)``, or any object with its
  ``read`` and ``release``), read by a thread that keeps the newest frame;
* :class:`Content`: what the projector is given to show, a still image or a video playing at its rate
  from the loop's start, in a loop.

Convention: frames uint8 RGB ``(H, W, 3)``; times in seconds on the camera's clock.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..checks import check_path
from ..errors import ProjregError
from .register import check_image
from .sources import load
from .video import MAX_FPS, VideoFile, check_fps, is_video, quiet_opencv

Clock = Callable[[], float]
DEFAULT_FPS = 30.0  # a camera or content video that states no frame rate is taken to run at this (the simulator's)
CAMERA_INDEXES = 10000  # OpenCV camera indexes: a device's number, plus a backend's offset (CAP_V4L2 200, ...)
DECODED_AHEAD = 2  # frames a played video's decoder may hold for the loop: bounded, as a camera driver's buffer


@dataclass(frozen=True)
class Shot:
    """A camera frame: its number since the camera started (every arrived frame counted), the image and
    the clock time it arrived."""

    index: int
    image: np.ndarray
    arrival: float


class PlayedVideo:
    """A video file played as a camera from :meth:`start`: frame ``k`` arrives at ``start + k / fps``.

    :meth:`take` returns the newest frame that has arrived and was not taken yet, waiting (``sleep``)
    for the next one when the last was already taken, and None once the video has ended and its last
    frame was taken or passed. Which frame is taken depends on the clock alone. A thread decodes the
    frames in order, at most ``DECODED_AHEAD`` ahead of the loop (a camera's driver decodes beside the
    program that reads it; decoding in the loop would charge the camera's work to the registration).

    Args:
        path: the video; ``option`` names it in errors.
        fps: its rate in frames per second, in (0, ``MAX_FPS``] (None: the rate its container states, else
            ``DEFAULT_FPS``).
        clock, sleep: the clock the frames arrive by and how to wait on it (a fake pair makes a test
            deterministic).
    """

    def __init__(
        self,
        path: Path,
        option: str = "--captured",
        fps: float | None = None,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        given = None if fps is None else check_fps(fps)
        self.video = VideoFile(check_path(option, path), option)
        self.fps = given or _stated_fps(self.video.fps)
        self.clock, self.sleep = clock, sleep
        self.start_time: float | None = None
        self._decoded: queue.Queue | None = None  # frames, then None at the end (or the decoder's error)
        self._running = False
        self._thread: threading.Thread | None = None
        self._popped = -1  # the last frame taken from the decoder ...
        self._frame: np.ndarray | None = None  # ... and its pixels
        self._taken = -1  # the last frame handed over
        self._ended = False

    def start(self) -> float:
        """Start playing now; the clock time of frame 0's arrival."""
        self._decoded, self._running = queue.Queue(maxsize=DECODED_AHEAD), True
        self._thread = threading.Thread(target=self._decode, name="projreg-played-video", daemon=True)
        self._thread.start()
        self.start_time = self.clock()
        return self.start_time

    def _decode(self) -> None:
        try:
            for frame in self.video:
                if not self._put(frame):
                    return
            self._put(None)
        except ProjregError as e:
            self._put(e)

    def _put(self, item: object) -> bool:
        """Hand ``item`` to the loop, waiting while ``DECODED_AHEAD`` are waiting; False once closed."""
        while self._running:
            try:
                self._decoded.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def take(self) -> Shot | None:
        """The newest frame not taken yet (see the class docstring)."""
        if self._decoded is None or self.start_time is None:
            raise ProjregError("a played video hands over frames once started")
        now = self.clock()
        newest = math.floor((now - self.start_time) * self.fps)
        if newest <= self._taken:  # the loop is ahead of the camera: wait for the next frame
            self.sleep(self.start_time + (self._taken + 1) / self.fps - now)
            newest = max(self._taken + 1, math.floor((self.clock() - self.start_time) * self.fps))
        while self._popped < newest and not self._ended:
            item = self._decoded.get()
            if isinstance(item, ProjregError):
                raise item
            self._ended = item is None
            if item is not None:
                self._popped, self._frame = self._popped + 1, item
        if self._popped <= self._taken:
            return None
        self._taken = self._popped
        return Shot(self._taken, self._frame, self.start_time + self._taken / self.fps)

    def arrived(self, now: float) -> int:
        """How many frames had arrived by clock time ``now`` (a video that ended: at most its frames)."""
        if self.start_time is None:
            return 0
        count = math.floor((now - self.start_time) * self.fps) + 1
        if self._ended:
            return min(count, self._popped + 1)
        return max(min(count, self.video.stated or count), self._taken + 1)

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


class DeviceCamera:
    """A camera read by a thread that keeps only its newest frame (a camera's own buffer would hand over
    stale frames): :meth:`take` returns the newest frame not taken yet, waiting for one, None once the
    camera stops giving frames.

    Args:
        source: an OpenCV camera index in 0..``CAMERA_INDEXES - 1`` (``cv2.VideoCapture(index)``, its
            own console messages off while it probes), or an object with ``read()`` and ``release()`` (a
            ``cv2.VideoCapture`` of a stream); ``option`` names it in errors.
        clock: the clock arrival times are read on.
    """

    def __init__(self, source: int | cv2.VideoCapture, option: str = "--captured", clock: Clock = time.monotonic):
        self.option, self.clock = option, clock
        if isinstance(source, int):
            if not 0 <= source < CAMERA_INDEXES:  # OpenCV crashes on -1 and overflows on 10**11
                raise ProjregError(f"{option} {source}: a camera index is in 0..{CAMERA_INDEXES - 1}; check the index")
            previous = quiet_opencv()
            try:
                capture = cv2.VideoCapture(source)
            finally:
                cv2.utils.logging.setLogLevel(previous)
            if not capture.isOpened():
                raise ProjregError(f"{option} {source}: OpenCV cannot open camera {source}; check the index")
        else:
            capture = source
        self._capture = capture
        self.fps = _stated_fps(capture.get(cv2.CAP_PROP_FPS) if hasattr(capture, "get") else None)
        self.start_time: float | None = None
        self._newest: Shot | None = None
        self._count = 0  # frames arrived
        self._taken = -1
        self._running = False
        self._ready = threading.Condition()
        self._thread: threading.Thread | None = None

    def start(self) -> float:
        self.start_time = self.clock()
        self._running = True
        self._thread = threading.Thread(target=self._read, name="projreg-camera", daemon=True)
        self._thread.start()
        return self.start_time

    def _read(self) -> None:
        while self._running:
            ok, bgr = self._capture.read()
            with self._ready:
                if not ok:
                    self._running = False
                else:
                    self._newest = Shot(self._count, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), self.clock())
                    self._count += 1
                self._ready.notify_all()

    def take(self) -> Shot | None:
        with self._ready:
            self._ready.wait_for(lambda: not self._running or self._newest_index() > self._taken)
            if self._newest_index() <= self._taken:
                return None
            self._taken = self._newest.index
            return self._newest

    def _newest_index(self) -> int:
        return -1 if self._newest is None else self._newest.index

    def arrived(self, now: float) -> int:
        """How many frames the camera has given."""
        return self._count

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._capture.release()


def _stated_fps(stated: float | None) -> float:
    """The rate a video or camera states, if it is one (in (0, ``MAX_FPS``]), else ``DEFAULT_FPS``."""
    return float(stated) if stated is not None and 0 < stated <= MAX_FPS else DEFAULT_FPS


class Content:
    """What the projector is given to show: one image (uint8 RGB ``(H, W, 3)`` or a file), or a video
    that plays at its rate (``fps`` in (0, ``MAX_FPS``]; None: its stated rate, else ``DEFAULT_FPS``)
    from :meth:`start`, looping; :meth:`at` gives the frame on show at a clock time and its number (an
    image: 0). A frame the video's container states but that does not read is an error when the show
    reaches it, as :class:`~projreg.inference.video.VideoFile`'s."""

    def __init__(self, source: np.ndarray | Path, option: str = "--content", fps: float | None = None) -> None:
        self.option = option
        self.video: VideoFile | None = None
        given = None if fps is None else check_fps(fps)
        if isinstance(source, np.ndarray):
            self.image = check_image(option, source)
        elif is_video(check_path(option, source)):
            self.video = VideoFile(Path(source), option)
            self.fps = given or _stated_fps(self.video.fps)
        else:
            self.image = load(Path(source))
        if self.video is None and given is not None:
            raise ProjregError(f"fps: {option} is a still image, shown without a frame rate; drop fps")
        self.start_time = 0.0
        self._capture: cv2.VideoCapture | None = None
        self._index, self._frame, self._length = -1, None, None

    def start(self, at: float) -> None:
        self.start_time = at

    def at(self, now: float) -> tuple[np.ndarray, int]:
        """The frame on show at clock time ``now`` and its number in the video."""
        if self.video is None:
            return self.image, 0
        target = max(0, math.floor((now - self.start_time) * self.fps))
        if self._length:
            target %= self._length
        if self._capture is None or target < self._index:  # the first call, or the video looped
            self.close()
            self._capture, self._index = self.video.open(), -1
        while self._index < target:
            ok, bgr = self._capture.read()
            if not ok:
                self.video.check_end(self._index + 1)  # a damaged or truncated file is not the video's end
                self._length = self._index + 1
                return self.at(now)
            self._index, self._frame = self._index + 1, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        return self._frame, self._index

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
