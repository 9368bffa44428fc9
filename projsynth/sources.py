"""Image sources: folders of natural / generated images (scikit-image's pictures: bench/real_sources.py).

A source lists its images deterministically, assigns each file to a split by a stable hash of its
relative path, and loads an image as ``H x W x 3`` uint8 RGB fitted to the dataset size.

Skipping unreadable files: ``FolderSource.load`` raises ``ProjsynthError`` whose message starts with
the file's path. A caller that skips bad files instead of stopping catches it, counts it and logs the
message, e.g. ``try: img = src.load(item, size) except ProjsynthError as err: skipped.append(str(err))``.
OpenCV's decoders' own lines about a broken file are silenced (:mod:`projsynth.native`).
"""

import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from . import ProjsynthError
from .native import native_output_silenced
from .procedural import KINDS, THEMES

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")
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


def list_images(folder: Path, option: str) -> list[Path]:
    """All image files under ``folder``, recursively, sorted by relative POSIX path.

    Extensions (``IMAGE_EXTENSIONS``) match case-insensitively; hidden files and folders (name
    starting with ``.``, e.g. macOS ``._x.png``) are skipped; symbolic links to folders are followed
    once. ``option`` (e.g. ``"--natural"``) names the setting in error messages.
    """
    folder = Path(folder)
    if not folder.exists():
        raise ProjsynthError(f"{option} {folder}: folder does not exist; "
                             f"point {option} at a folder of images")
    if not folder.is_dir():
        raise ProjsynthError(f"{option} {folder}: not a folder; point {option} at a folder of images")
    found, seen = [], set()
    for root, dirs, files in os.walk(folder, followlinks=True):
        real = os.path.realpath(root)
        if real in seen:  # a link cycle
            dirs[:] = []
            continue
        seen.add(real)
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        found += [Path(root, f) for f in files
                  if not f.startswith(".") and f.lower().endswith(IMAGE_EXTENSIONS)]
    if not found:
        raise ProjsynthError(f"{option} {folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) found; "
                             f"add images or point {option} elsewhere")
    return sorted(found, key=lambda p: p.relative_to(folder).as_posix())


def load_image(path: Path) -> np.ndarray:
    """Read an image file as ``H x W x 3`` uint8 RGB.

    8-bit as is; 16-bit as ``round(v / 257)``; float (e.g. TIFF) clipped to [0, 1] then scaled by 255
    (NaN -> 0); gray replicated to three channels; an alpha channel is dropped (not composited).
    Unicode paths work (the bytes are read by numpy and decoded by OpenCV).

    Raises:
        ProjsynthError: the file is missing, not a regular file (a FIFO, a device), empty, truncated, not
            an image or of an unsupported type.
    """
    image = read_image(path)
    if image.dtype == np.uint16:
        image = ((image.astype(np.uint32) + 128) // 257).astype(np.uint8)  # exact round(v / 257)
    elif image.dtype.kind == "f":
        image = (np.clip(np.nan_to_num(image, nan=0.0), 0, 1) * 255 + 0.5).astype(np.uint8)
    channels = image.shape[2]
    if channels in (1, 2):  # gray, gray + alpha
        return np.repeat(image[..., :1], 3, axis=2)
    return cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2RGB)  # BGR, BGRA


def load_gray(path: Path) -> np.ndarray:
    """Read an image file as ``H x W`` float32 grey in [0, 1] at its full bit depth (photos to decode).

    8-bit divided by 255, 16-bit by 65535, float clipped to [0, 1] (NaN -> 0); colour is the mean of
    the three channels; alpha is dropped. Errors as :func:`load_image`.
    """
    image = read_image(path)
    if image.dtype == np.uint8:
        gray = image[..., :3].astype(np.float32) / np.float32(255)
    elif image.dtype == np.uint16:
        gray = image[..., :3].astype(np.float32) / np.float32(65535)
    else:
        gray = np.clip(np.nan_to_num(image[..., :3].astype(np.float32), nan=0.0), 0, 1)
    return gray[..., 0] if image.shape[2] < 3 else gray.mean(axis=2, dtype=np.float32)


def read_image(path: Path) -> np.ndarray:
    """An image file decoded by OpenCV as ``H x W x C`` (C 1-4, BGR order), uint8, uint16 or float.

    Raises:
        ProjsynthError: the file is missing, empty, truncated, not an image or of an unsupported type.
    """
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # reading a FIFO or a device would block or never end
            raise ProjsynthError(f"{path}: cannot read image (not a regular file); remove it or replace it by a file")
        data = np.fromfile(path, np.uint8)
    except OSError as err:
        reason = err.strerror or str(err)
        raise ProjsynthError(f"{path}: cannot read image ({reason}); check the path") from err
    if data.size == 0:
        raise ProjsynthError(f"{path}: cannot read image (empty file); remove it or fix it")
    try:
        with native_output_silenced():  # libpng/libtiff's own lines about a damaged file
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error as err:  # some corrupt headers raise instead of returning None
        raise ProjsynthError(f"{path}: cannot read image (decoder error); remove it or fix it") from err
    if image is None or image.size == 0:
        raise ProjsynthError(f"{path}: cannot read image (not a complete image file); remove it or fix it")
    if image.dtype not in (np.uint8, np.uint16) and image.dtype.kind != "f":
        raise ProjsynthError(f"{path}: cannot read image (unsupported sample type {image.dtype}); "
                             "convert it to 8/16-bit or float")
    if image.ndim == 2:
        image = image[..., None]
    if image.shape[2] > 4:
        raise ProjsynthError(f"{path}: cannot read image ({image.shape[2]} channels); remove it or fix it")
    return image


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
