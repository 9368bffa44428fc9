"""The frames of one side of a sequence (what ``predict``, ``compensate`` and ``live`` read): a folder of
images (in name order), a video file (:mod:`projreg.inference.video`), or one still image.

Two sides are paired frame by frame in order; a still image stands for every frame of the other side
(a projector showing one picture while the camera films). Before anything is written, :func:`survey`
reads every frame once: how many there are, that each reads, and that they share one size.

Convention: frames uint8 RGB ``(H, W, 3)``.
"""

from __future__ import annotations

from collections.abc import Iterator
from itertools import islice, repeat
from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.utils.images import list_images, load_image

from ..errors import ProjregError
from .video import VideoFile, is_video

KINDS = ("folder", "video", "still")


class Frames:
    """The frames at ``path`` (module docstring); ``option`` names them in errors.

    ``kind``: ``folder``, ``video`` or ``still``; ``files``: every file read (the folder's images, or the
    one file); ``names``: one name per frame (a folder's relative paths, a video's frame numbers
    ``000000``, ...; a still image: its file name); ``fps``: a video's frame rate, else None.

    Raises:
        ProjregError: an empty folder, a file that is not there or a video FFmpeg cannot open.
    """

    def __init__(self, path: Path, option: str) -> None:
        self.path, self.option = Path(path), option
        self.fps: float | None = None
        if self.path.is_dir():
            self.kind = "folder"
            try:
                self.files = list_images(self.path, option)
            except ProjsynthError as e:
                raise ProjregError(str(e)) from e
        elif is_video(self.path):
            self.kind, self.files = "video", [self.path]
            self.video = VideoFile(self.path, option)
            self.fps = self.video.fps
        else:
            self.kind, self.files = "still", [self.path]

    @property
    def sequence(self) -> bool:
        """Whether these are the frames of a sequence (a folder or a video), not one still image."""
        return self.kind != "still"

    def names(self, count: int) -> list[str]:
        """A name per frame for ``count`` frames (module docstring)."""
        if self.kind == "folder":
            return [p.relative_to(self.path).as_posix() for p in self.files]
        if self.kind == "video":
            return [f"{k:06d}" for k in range(count)]
        return [self.path.name] * count

    def where(self, k: int) -> str:
        """Frame ``k`` as errors name it: its file, or the video and the frame's number."""
        if self.kind == "folder":
            return str(self.files[k])
        return f"{self.path} frame {k}" if self.kind == "video" else str(self.path)

    def __iter__(self) -> Iterator[np.ndarray]:
        """The frames in order, each read when asked for; a still image without end."""
        if self.kind == "video":
            yield from self.video
        elif self.kind == "folder":
            for path in self.files:
                yield load(path)
        else:
            yield from repeat(load(self.path))


def survey(frames: Frames, check_size: bool = True) -> list[tuple[int, ...]]:
    """Every frame read once (a still image: its one): their shapes, in order; with ``check_size``,
    refused unless they share the first one's size.

    Raises:
        ProjregError: a frame that does not read, or (``check_size``) one of another size, named.
    """
    shapes = []
    for k, frame in enumerate(frames if frames.sequence else islice(frames, 1)):
        shapes.append(frame.shape)
        if check_size and frame.shape != shapes[0]:
            (h, w), (h0, w0) = frame.shape[:2], shapes[0][:2]
            raise ProjregError(
                f"{frames.option} {frames.where(k)} is {w}x{h} px but {frames.where(0)}, the sequence's first frame, "
                f"is {w0}x{h0}; the frames of one sequence share one size (nothing was written)"
            )
    return shapes


def paired_count(projected: Frames, captured: Frames, counts: tuple[int, int]) -> int:
    """The number of pairs of two sides with ``counts`` frames each (a still image pairs with every frame).

    Raises:
        ProjregError: two sequences whose frame counts differ, or two still images where frames are wanted.
    """
    if projected.sequence and captured.sequence and counts[0] != counts[1]:
        raise ProjregError(
            f"--projected {projected.path} has {counts[0]} frames but --captured {captured.path} has {counts[1]}; "
            "the frames are paired in order, so both sides need as many (nothing was written)"
        )
    return counts[1] if captured.sequence else counts[0]


def load(path: Path) -> np.ndarray:
    """One image file as uint8 RGB, its errors as one :class:`ProjregError` line."""
    try:
        return load_image(path)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
