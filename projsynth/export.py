"""``projsynth export`` and ``projsynth preview``: shards to ordinary files people can open."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from . import ProjsynthError
from .flowio import decode_flow_exr, flow_to_color, write_atomic, write_flo
from .shards import load_manifest, open_shard


def _write_png(path: Path, rgb: np.ndarray) -> None:
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb):
        raise ProjsynthError(f"{path}: cannot write PNG; check the directory is writable and has space")


def export(root: Path, out: Path, limit: int | None = None) -> int:
    """Write each sample as ``ID_projected.png``, ``ID_captured.png``, ``ID_valid.png``,
    ``ID_flow.exr`` (the stored bytes, unchanged), ``ID_flow.flo`` and ``ID_flow.png`` (colour wheel).

    Returns:
        The number of samples exported.
    """
    if limit is not None and limit < 1:
        raise ProjsynthError(f"--limit: must be >= 1, got {limit}")
    manifest = load_manifest(root)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create directory ({e.strerror})") from e
    n = 0
    for entry in manifest["shards"]:
        with open_shard(Path(root) / entry["file"]) as f:
            for i in range(entry["count"]):
                if limit is not None and n >= limit:
                    return n
                sid = f["sample_id"][i].decode()
                data = f["flow_exr"][i].tobytes()
                flow, valid, _ = decode_flow_exr(data)
                write_atomic(out / f"{sid}_flow.exr", data)
                write_flo(out / f"{sid}_flow.flo", flow, valid)
                _write_png(out / f"{sid}_projected.png", f["projected"][i])
                _write_png(out / f"{sid}_captured.png", f["captured"][i])
                _write_png(out / f"{sid}_valid.png", valid.astype(np.uint8) * 255)
                _write_png(out / f"{sid}_flow.png", flow_to_color(flow, valid))
                n += 1
    return n


def preview(root: Path, out: Path, count: int = 8) -> int:
    """Contact sheet: one row per sample, ``projected | captured | flow colour | valid``.

    Samples are spread evenly over the dataset so several transform families show.
    """
    if count < 1:
        raise ProjsynthError(f"--count: must be >= 1, got {count}")
    manifest = load_manifest(root)
    total, size = manifest["num_samples"], manifest["shard_size"]
    rows = []
    for k in np.linspace(0, total - 1, min(count, total)).astype(int):
        j, i = divmod(int(k), size)
        with open_shard(Path(root) / manifest["shards"][j]["file"]) as f:
            flow, valid, _ = decode_flow_exr(f["flow_exr"][i].tobytes())
            gray = np.repeat((valid.astype(np.uint8) * 255)[..., None], 3, axis=2)
            row = np.hstack([f["projected"][i], f["captured"][i], flow_to_color(flow, valid), gray])
            label = f["sample_id"][i].decode()
        cv2.putText(row, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2, cv2.LINE_AA)
        cv2.putText(row, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        rows.append(row)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create its folder ({e.strerror})") from e
    _write_png(out, np.vstack(rows))
    return len(rows)
