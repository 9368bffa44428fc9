"""The files ``predict`` and ``compensate`` write: named as their format, never over an input, whole or not at all."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from projsynth.errors import ProjsynthError
from projsynth.utils.files import write_atomic
from projsynth.utils.images import png_bytes
from projsynth.utils.outputs import refuse_overwriting_inputs

from ..errors import ProjregError


def require_suffix(path: Path, suffix: str, option: str) -> None:
    """Refuse an output name whose extension promises another format than the one written."""
    if path.suffix.lower() != suffix:
        raise ProjregError(
            f"{option} {path}: this file is written as {suffix[1:].upper()}; give a name ending in {suffix}"
        )


def check_parent(path: Path, option: str) -> None:
    """Refuse an output whose folder cannot be: a regular file where a folder of its path would go
    (``afile/o.mkv``), found before any work, rather than when the file is written."""
    folder = Path(path).parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if folder.exists() and not folder.is_dir():
        raise ProjregError(f"{option} {path}: cannot write ({folder} is a file, not a folder); check the directory")


def guard_outputs(outputs: list, inputs: list) -> None:
    """:func:`projsynth.utils.outputs.refuse_overwriting_inputs` as a :class:`ProjregError`."""
    try:
        refuse_overwriting_inputs(outputs, inputs)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from None


def write_png(path: Path, image: np.ndarray) -> None:
    """Atomic PNG write (temporary file, fsync, rename); errors become one ProjregError naming the file."""
    try:
        write_atomic(Path(path), png_bytes(path, image))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
