"""``projsynth export`` and ``projsynth preview``: shards to ordinary files people can open."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ..errors import ProjsynthError
from ..flow.formats import write_flo
from ..flow.pictures import fit, flow_picture, flow_to_color, font_scale, legend, put_label, scale_of, text_height
from ..utils.files import write_atomic
from ..utils.images import png_bytes
from .shards import ShardReader


def _write_png(path: Path, image: np.ndarray) -> None:
    write_atomic(path, png_bytes(path, image))


def export(root: Path, out: Path, limit: int | None = None, progress: Callable[[int], None] | None = None,
           progress_total: Callable[[int], None] | None = None, max_flow: float | None = None) -> int:
    """Write each sample as ``ID_projected.png``, ``ID_captured.png``, ``ID_valid.png``,
    ``ID_flow.exr`` (the stored bytes, unchanged), ``ID_flow.flo`` and ``ID_flow.png`` (colour wheel
    over a legend: ``flowviz.flow_picture``, saturating at ``max_flow`` px, else at each sample's own
    largest magnitude).

    Every file is written atomically; a damaged shard stops the export with one error naming it.

    Returns:
        The number of samples exported.
    """
    if limit is not None and limit < 1:
        raise ProjsynthError(f"--limit: must be >= 1, got {limit}")
    if max_flow is not None:
        scale_of(np.zeros((1, 1, 2), np.float32), None, max_flow)  # refused before any file is written
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
            _write_png(out / f"{sid}_flow.png", flow_picture(flow, valid, max_flow))
            if progress:
                progress(1)
    finally:
        reader.close()
    return n


COLUMNS = ("projected", "captured", "flow", "valid")


def preview(root: Path, out: Path, count: int = 8, max_flow: float | None = None) -> int:
    """Contact sheet (a PNG): one row per sample, ``projected | captured | flow colour | valid``.

    Samples are spread evenly over the dataset so several transform families show. A header names
    the columns; each row is labelled with its sample id, transform (name, severity, condition) and
    the magnitude its flow colours saturate at (``max_flow`` px for every row, else the row's own
    largest), in a strip above its pictures (they are not drawn over); a legend with the colour
    wheel closes the sheet. Layout: header (``label_height(W)`` px), then per row a label strip of
    that height and the ``H``-px pictures, then the legend.
    """
    if count < 1:
        raise ProjsynthError(f"--count: must be >= 1, got {count}")
    if out.suffix.lower() != ".png":
        raise ProjsynthError(f"--out {out}: the contact sheet is a PNG; give a name ending in .png")
    if max_flow is not None:
        scale_of(np.zeros((1, 1, 2), np.float32), None, max_flow)
    reader = ShardReader(root)
    rows = []
    try:
        for k in np.linspace(0, len(reader) - 1, min(count, len(reader))).astype(int):
            s = reader.read(int(k))
            gray = np.repeat((s["valid"].astype(np.uint8) * 255)[..., None], 3, axis=2)
            h, w = gray.shape[:2]
            captured = s["captured"] if s["captured"].shape[:2] == (h, w) else cv2.resize(s["captured"], (w, h))
            m = scale_of(s["flow"], s["valid"], max_flow)
            row = np.hstack([s["projected"], captured, flow_to_color(s["flow"], s["valid"], m), gray])
            t = s["params"]["transform"]
            label = _row_label(w, f"{s['params']['sample_id']}  {t['name']}  (flow: full colour {m:.3g} px)")
            row = np.vstack([label, row])
            rows.append(row)
    finally:
        reader.close()
    width = rows[0].shape[1]
    note = "full colour: --max-flow" if max_flow else "full colour: each row's own scale (in its label)"
    key = legend(width, max_flow, note, font_scale(width // 4))
    sheet = np.vstack([_header(width // 4, width), *rows, key])
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create its folder ({e.strerror})") from e
    _write_png(out, sheet)
    return len(rows)


def label_height(column: int) -> int:
    """Height of the header and of each row's label strip, over columns ``column`` px wide."""
    return text_height(font_scale(column)) + 14


def _row_label(column: int, text: str) -> np.ndarray:
    """A row's label strip, ``text`` from the left (smaller when it would not fit)."""
    strip = np.full((label_height(column), 4 * column, 3), 250, np.uint8)
    put_label(strip, text, (6, strip.shape[0] - 7), fit(text, 4 * column - 12, font_scale(column)))
    return strip


def _header(column: int, width: int) -> np.ndarray:
    """The column names, centred over columns ``column`` px wide."""
    scale = font_scale(column)
    header = np.full((label_height(column), width, 3), 225, np.uint8)
    for i, name in enumerate(COLUMNS):
        s = fit(name, column - 4, scale)
        tw = cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, s, max(1, round(s * 2)))[0][0]
        put_label(header, name, (i * column + max(0, (column - tw) // 2), header.shape[0] - 7), s)
    return header
