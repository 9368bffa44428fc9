"""Image files: find them in a folder, read them (any bit depth and channel count, as RGB uint8 or as
grey at full depth) and encode PNGs. Errors name the file in one line.

Convention: images ``H x W x 3`` uint8 RGB, origin top-left.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import cv2
import numpy as np

from ..errors import ProjsynthError
from .native import native_output_silenced


def png_bytes(path: Path, image: np.ndarray) -> bytes:
    """``image`` (``H x W x 3`` RGB or ``H x W`` gray, uint8) encoded as a PNG file destined for ``path``."""
    ok, data = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image)
    if not ok:
        raise ProjsynthError(f"{path}: cannot encode PNG of shape {image.shape}")
    return data.tobytes()


IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")


def list_images(folder: Path, option: str) -> list[Path]:
    """All image files under ``folder``, recursively, sorted by relative POSIX path.

    Extensions (``IMAGE_EXTENSIONS``) match case-insensitively; hidden files and folders (name
    starting with ``.``, e.g. macOS ``._x.png``) are skipped; symbolic links to folders are followed
    once. ``option`` (e.g. ``"--natural"``) names the setting in error messages.
    """
    folder = Path(folder)
    if not folder.exists():
        raise ProjsynthError(f"{option} {folder}: folder does not exist; point {option} at a folder of images")
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
        found += [Path(root, f) for f in files if not f.startswith(".") and f.lower().endswith(IMAGE_EXTENSIONS)]
    if not found:
        raise ProjsynthError(
            f"{option} {folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) found; "
            f"add images or point {option} elsewhere"
        )
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
    image = _full_scale(read_image(path))
    return image[..., 0] if image.shape[2] < 3 else image.mean(axis=2, dtype=np.float32)


def load_rgb(path: Path) -> np.ndarray:
    """Read an image file as ``H x W x 3`` float32 RGB in [0, 1] at its full bit depth (photos whose
    channels are measured apart); grey is replicated, alpha dropped, values as :func:`load_gray`'s."""
    image = _full_scale(read_image(path))
    return np.repeat(image[..., :1], 3, axis=2) if image.shape[2] < 3 else np.ascontiguousarray(image[..., 2::-1])


def _full_scale(image: np.ndarray) -> np.ndarray:
    """The first three channels (BGR, or fewer) of a decoded image as float32 in [0, 1] of full scale."""
    if image.dtype == np.uint8:
        return image[..., :3].astype(np.float32) / np.float32(255)
    if image.dtype == np.uint16:
        return image[..., :3].astype(np.float32) / np.float32(65535)
    return np.clip(np.nan_to_num(image[..., :3].astype(np.float32), nan=0.0), 0, 1)


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
        raise ProjsynthError(
            f"{path}: cannot read image (unsupported sample type {image.dtype}); convert it to 8/16-bit or float"
        )
    if image.ndim == 2:
        image = image[..., None]
    if image.shape[2] > 4:
        raise ProjsynthError(f"{path}: cannot read image ({image.shape[2]} channels); remove it or fix it")
    return image
