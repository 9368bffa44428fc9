"""``projsynth export`` and ``projsynth preview``: shards to ordinary files people can open."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from . import ProjsynthError
from .flowio import flow_to_color, write_atomic, write_flo
from .shards import ShardReader


def png_bytes(path: Path, image: np.ndarray) -> bytes:
    """``image`` (``H x W x 3`` RGB or ``H x W`` gray, uint8) encoded as a PNG file destined for ``path``."""
    ok, data = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image)
    if not ok:
        raise ProjsynthError(f"{path}: cannot encode PNG of shape {image.shape}")
    return data.tobytes()


def _write_png(path: Path, image: np.ndarray) -> None:
    write_atomic(path, png_bytes(path, image))


def export(root: Path, out: Path, limit: int | None = None, progress: Callable[[int], None] | None = None,
           progress_total: Callable[[int], None] | None = None) -> int:
    """Write each sample as ``ID_projected.png``, ``ID_captured.png``, ``ID_valid.png``,
    ``ID_flow.exr`` (the stored bytes, unchanged), ``ID_flow.flo`` and ``ID_flow.png`` (colour wheel).

    Every file is written atomically; a damaged shard stops the export with one error naming it.

    Returns:
        The number of samples exported.
    """
    if limit is not None and limit < 1:
        raise ProjsynthError(f"--limit: must be >= 1, got {limit}")
    reader = ShardReader(root)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create directory ({e.strerror})") from e
    n = len(reader) if limit is None else min(limit, len(reader))
    if progress_total:
        progress_total(n)
    try:
        for k in range(n):
            s = reader.read(k, flow_exr=True)
            sid, flow, valid = s["params"]["sample_id"], s["flow"], s["valid"]
            write_atomic(out / f"{sid}_flow.exr", s["flow_exr"])
            write_flo(out / f"{sid}_flow.flo", flow, valid)
            _write_png(out / f"{sid}_projected.png", s["projected"])
            _write_png(out / f"{sid}_captured.png", s["captured"])
            _write_png(out / f"{sid}_valid.png", valid.astype(np.uint8) * 255)
            _write_png(out / f"{sid}_flow.png", flow_to_color(flow, valid))
            if progress:
                progress(1)
    finally:
        reader.close()
    return n


def preview(root: Path, out: Path, count: int = 8) -> int:
    """Contact sheet (a PNG): one row per sample, ``projected | captured | flow colour | valid``.

    Samples are spread evenly over the dataset so several transform families show.
    """
    if count < 1:
        raise ProjsynthError(f"--count: must be >= 1, got {count}")
    if out.suffix.lower() != ".png":
        raise ProjsynthError(f"--out {out}: the contact sheet is a PNG; give a name ending in .png")
    reader = ShardReader(root)
    rows = []
    try:
        for k in np.linspace(0, len(reader) - 1, min(count, len(reader))).astype(int):
            s = reader.read(int(k))
            gray = np.repeat((s["valid"].astype(np.uint8) * 255)[..., None], 3, axis=2)
            h, w = gray.shape[:2]
            captured = s["captured"] if s["captured"].shape[:2] == (h, w) else cv2.resize(s["captured"], (w, h))
            row = np.hstack([s["projected"], captured, flow_to_color(s["flow"], s["valid"]), gray])
            label = s["params"]["sample_id"]
            cv2.putText(row, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.putText(row, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
            rows.append(row)
    finally:
        reader.close()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create its folder ({e.strerror})") from e
    _write_png(out, np.vstack(rows))
    return len(rows)
