"""Image sources: folders of natural / generated images (scikit-image's pictures: bench/real_sources.py).

A source lists its images deterministically, assigns each file to a split by a stable hash of its
relative path, and loads an image as ``H x W x 3`` uint8 RGB fitted to the dataset size.

Skipping unreadable files: ``FolderSource.load`` raises ``ProjsynthError`` whose message starts with
the file's path. A caller that skips bad files instead of stopping catches it, counts it and logs the
message, e.g. ``try: img = src.load(item, size) except ProjsynthError as err: skipped.append(str(err))``.
OpenCV's decoders' own lines about a broken file are silenced (:mod:`projsynth.utils.native`).
"""

import hashlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import ProjsynthError
from ..utils.images import list_images, load_image
from .procedural import KINDS, THEMES

MIN_SOURCE_SIDE = 32
# "all" takes every image: a folder held out from training, used whole as a test set
SPLITS = ("train", "val", "test", "all")


@dataclass(frozen=True)
class SourceImage:
    """Where one source image comes from.

    ``kind``: ``"natural"`` or ``"generated"``; ``name``: relative POSIX path inside the folder (or
    a procedural name); ``theme``: scene label or None; ``path``: the file,
    None for images that are not files.
    """

    kind: str
    name: str
    theme: str | None
    path: Path | None


def fit_to_size(image: np.ndarray, size: tuple[int, int], name: str = "image") -> np.ndarray:
    """Centre-crop ``image`` to the aspect ratio of ``size`` = ``(H, W)``, then resize to it.

    Shrinking uses ``INTER_AREA`` (no aliasing), enlarging ``INTER_CUBIC``. ``name`` is used in errors.

    Raises:
        ProjsynthError: a side of ``image`` is below ``MIN_SOURCE_SIDE``.
    """
    out_h, out_w = (int(v) for v in size)
    h, w = image.shape[:2]
    if min(h, w) < MIN_SOURCE_SIDE:
        raise ProjsynthError(f"{name}: image is too small ({w}x{h} px, need >= {MIN_SOURCE_SIDE} px a side); "
                             "remove it or use a larger one")
    if w * out_h > h * out_w:  # wider than the target: crop columns
        crop_h, crop_w = h, max(1, round(h * out_w / out_h))
    else:
        crop_h, crop_w = max(1, round(w * out_h / out_w)), w
    y0, x0 = (h - crop_h) // 2, (w - crop_w) // 2
    crop = image[y0:y0 + crop_h, x0:x0 + crop_w]
    if (crop_h, crop_w) == (out_h, out_w):
        return np.ascontiguousarray(crop)
    interp = cv2.INTER_AREA if crop_w > out_w else cv2.INTER_CUBIC
    return cv2.resize(crop, (out_w, out_h), interpolation=interp)


def scene_label(path: Path, root: Path) -> str | None:
    """The scene theme of ``path``: its first folder under ``root`` if that is one of ``THEMES``."""
    parts = Path(path).relative_to(root).parts
    label = parts[0].lower() if len(parts) > 1 else None
    return label if label in THEMES else None


def split_of(relpath: str, seed: int) -> str:
    """``"train"`` (80 %), ``"val"`` (10 %) or ``"test"`` (10 %) from sha256 of ``f"{seed}:{relpath}"``.

    Each file's split depends on its own name only, so adding files never moves existing ones.
    """
    u = int.from_bytes(hashlib.sha256(f"{seed}:{relpath}".encode()).digest()[:8], "big") / 2**64
    return "train" if u < 0.8 else "val" if u < 0.9 else "test"


def _for_split(images: tuple[SourceImage, ...], split: str, seed: int) -> list[SourceImage]:
    if split not in SPLITS:
        raise ProjsynthError(f"split {split!r} is unknown; use one of {', '.join(SPLITS)}")
    chosen = [im for im in images if split == "all" or split_of(im.name, seed) == split]
    order = np.random.default_rng([seed, SPLITS.index(split)]).permutation(len(chosen))
    return [chosen[i] for i in order]


class FolderSource:
    """The images of one kind under a folder (see ``list_images``), with scene labels from subfolders."""

    def __init__(self, folder: Path, kind: str, option: str):
        if kind not in KINDS:
            raise ProjsynthError(f"source kind {kind!r} is unknown; use one of {', '.join(KINDS)}")
        self.folder, self.kind = Path(folder), kind
        self.images = tuple(
            SourceImage(kind, p.relative_to(self.folder).as_posix(), scene_label(p, self.folder), p)
            for p in list_images(self.folder, option)
        )

    def files_for_split(self, split: str, seed: int) -> list[SourceImage]:
        """This split's images in a shuffled order that depends only on ``seed`` and the file names."""
        return _for_split(self.images, split, seed)

    def load(self, src: SourceImage, size: tuple[int, int]) -> np.ndarray:
        """``load_image`` then ``fit_to_size``: ``H x W x 3`` uint8 RGB; ProjsynthError names the file."""
        return fit_to_size(load_image(src.path), size, name=str(src.path))
