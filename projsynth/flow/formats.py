"""Flow files: OpenEXR in memory (the shard format), Middlebury ``.flo``, and the colour wheel.

Convention: flow is forward, projected -> captured, float32 ``(H, W, 2)`` in pixels on the projected
grid, ``flow[y, x] = (u, v)``; ``valid`` is bool ``(H, W)``.
"""

import io
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import ProjsynthError
from ..utils.files import write_atomic
from ..utils.native import native_output_silenced

EXR_CHANNELS = ("forward.u", "forward.v", "valid")
CONFIDENCE_CHANNEL = "confidence"  # optional: a prediction's per-pixel confidence in [0, 1] (projreg predict)
FLO_MAGIC = 202021.25  # the bytes b"PIEH" read as a little-endian float32
FLO_UNKNOWN = 1e10  # Middlebury readers treat a component > 1e9 as unknown flow
_COMPRESSIONS = {"zip": OpenEXR.ZIP_COMPRESSION, "pxr24": OpenEXR.PXR24_COMPRESSION}


def _as_flow(flow: np.ndarray, where: str) -> np.ndarray:
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2 or 0 in flow.shape or not np.issubdtype(flow.dtype, np.floating):
        raise ProjsynthError(f"{where}: flow must be a float (H, W, 2) array, got {flow.dtype} {flow.shape}")
    return np.ascontiguousarray(flow, dtype=np.float32)


def _as_valid(valid: np.ndarray, shape: tuple[int, ...], where: str) -> np.ndarray:
    valid = np.asarray(valid)
    if valid.dtype != np.bool_ or valid.shape != shape[:2]:
        raise ProjsynthError(f"{where}: valid must be a bool {shape[:2]} array, got {valid.dtype}{valid.shape}")
    return valid


def encode_flow_exr(
    flow: np.ndarray,
    valid: np.ndarray,
    sample_id: str,
    compression: str = "zip",
    attrs: dict[str, str] | None = None,
    confidence: np.ndarray | None = None,
) -> bytes:
    """Encode one sample's flow as a complete single-part scanline OpenEXR file, in memory.

    OpenEXR 3.5's ``File.write`` accepts a binary stream, so the file is written into an
    ``io.BytesIO``; nothing touches the disk. Every channel is passed as its own C-contiguous copy
    (the bindings silently corrupt strided arrays). The bytes are a pure function of the arguments.

    Args:
        flow: ``(H, W, 2)`` floating array; stored as float32.
        valid: ``(H, W)`` bool mask; stored as a FLOAT channel holding exactly 0.0 or 1.0.
        sample_id: stored in the ``sample_id`` header attribute.
        compression: ``"zip"`` (lossless, the default) or ``"pxr24"`` (lossy: float32 rounded to
            24 bits, so the error is at most ``|flow| * 2**-16``, i.e. <= 2**-8 = 0.0039 px for
            ``|flow| < 512``; ``valid`` stays exact).
        attrs: more string header attributes (e.g. ``projreg predict``'s ``registered``); they
            cannot replace the ones above.
        confidence: optional float ``(H, W)`` in [0, 1], stored as the FLOAT channel ``confidence``
            (``projreg predict``'s per-pixel confidence).

    Returns:
        The EXR file: channels ``forward.u``, ``forward.v``, ``valid`` (FLOAT), and ``confidence`` when
        given; string attributes ``units="px"``, ``direction="projected->captured"``, ``sample_id``.

    Convention: flow projected -> captured, in px, ``flow[y, x] = (u, v)``.

    Example:
        >>> data = encode_flow_exr(np.zeros((2, 3, 2), np.float32), np.ones((2, 3), bool), "s0")
        >>> data[:4] == b"\\x76\\x2f\\x31\\x01"  # the OpenEXR magic number
        True
    """
    where = f"sample {sample_id!r}"
    if not isinstance(sample_id, str):
        raise ProjsynthError(f"{where}: sample_id must be a str, got {type(sample_id).__name__}")
    if compression not in _COMPRESSIONS:
        raise ProjsynthError(f"{where}: unknown EXR compression {compression!r}; use 'zip' or 'pxr24'")
    flow = _as_flow(flow, where)
    valid = _as_valid(valid, flow.shape, where)
    header = {
        **{str(k): str(v) for k, v in (attrs or {}).items()},
        "compression": _COMPRESSIONS[compression],
        "type": OpenEXR.scanlineimage,
        "units": "px",
        "direction": "projected->captured",
        "sample_id": sample_id,
    }
    channels = {
        "forward.u": np.ascontiguousarray(flow[..., 0]),
        "forward.v": np.ascontiguousarray(flow[..., 1]),
        "valid": np.ascontiguousarray(valid, dtype=np.float32),  # astype() would keep an F-order layout
    }
    if confidence is not None:
        confidence = np.asarray(confidence)
        if confidence.shape != valid.shape or not np.isfinite(confidence).all():
            raise ProjsynthError(f"{where}: confidence must be a finite {valid.shape} array, got {confidence.shape}")
        channels[CONFIDENCE_CHANNEL] = np.ascontiguousarray(np.clip(confidence, 0, 1), dtype=np.float32)
    buf = io.BytesIO()
    OpenEXR.File(header, channels).write(buf)
    return buf.getvalue()


@dataclass(frozen=True)
class FlowFile:
    """A decoded flow EXR: ``flow`` float32 ``(H, W, 2)``, ``valid`` bool ``(H, W)``, the string
    ``header`` attributes, and ``confidence`` float32 ``(H, W)`` when the file has that channel."""

    flow: np.ndarray
    valid: np.ndarray
    header: dict[str, str]
    confidence: np.ndarray | None = None


def decode_flow_exr(data: bytes) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    """Decode an OpenEXR flow file held in memory (the inverse of :func:`encode_flow_exr`).

    Corrupt input raises ``ProjsynthError``. Note that on corrupt input the OpenEXR bindings also
    print their own diagnostics (a warning on stdout, ``EXR_ERR_*`` lines on stderr).

    Args:
        data: the bytes of a complete EXR file with channels ``forward.u``, ``forward.v``, ``valid``.

    Returns:
        ``(flow, valid, header)``: flow float32 ``(H, W, 2)`` C-contiguous, valid bool ``(H, W)``
        (channel value > 0.5), and the file's string header attributes.

    Convention: flow projected -> captured, in px, ``flow[y, x] = (u, v)``.
    """
    f = decode_flow_file(data)
    return f.flow, f.valid, f.header


def decode_flow_file(data: bytes) -> FlowFile:
    """:func:`decode_flow_exr` with the optional ``confidence`` channel (:class:`FlowFile`)."""

    def invalid(why: str) -> ProjsynthError:
        return ProjsynthError(f"not a valid OpenEXR flow file: {why}; regenerate or re-export it")

    try:
        exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
        header, channels = exr.header(), exr.channels()
    except Exception as e:  # the bindings raise RuntimeError, ValueError or TypeError
        raise invalid(f"{type(e).__name__}: {' '.join(str(e).split())}") from e
    missing = [name for name in EXR_CHANNELS if name not in channels]
    if missing:
        raise invalid(f"missing channel(s) {', '.join(missing)}")
    u, v, m = (channels[name].pixels for name in EXR_CHANNELS)
    if not u.shape == v.shape == m.shape or u.ndim != 2:
        raise invalid(f"channel shapes differ: {u.shape}, {v.shape}, {m.shape}")
    flow = np.stack([u, v], axis=-1).astype(np.float32, copy=False)  # [H, W, 2]
    attrs = {key: value for key, value in header.items() if isinstance(value, str)}
    confidence = None
    if CONFIDENCE_CHANNEL in channels:
        confidence = np.asarray(channels[CONFIDENCE_CHANNEL].pixels, np.float32)
        if confidence.shape != m.shape:
            raise invalid(f"channel {CONFIDENCE_CHANNEL} has shape {confidence.shape}, the flow {m.shape}")
    return FlowFile(flow, m > 0.5, attrs, confidence)


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise ProjsynthError(f"{path}: cannot read ({e.strerror or e}); check the path") from e


def read_flow_exr(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    """Read an EXR flow file from disk; returns ``(flow, valid, header)`` as :func:`decode_flow_exr`."""
    f = read_flow_file(path)
    return f.flow, f.valid, f.header


def read_flow_file(path: str | os.PathLike[str]) -> FlowFile:
    """Read an EXR flow file from disk, with its optional confidence (:class:`FlowFile`)."""
    path = Path(path)
    data = _read_bytes(path)  # its error already names the file
    try:
        with native_output_silenced():  # a damaged file: OpenEXR's own lines before ours
            return decode_flow_file(data)
    except ProjsynthError as e:
        raise ProjsynthError(f"{path}: {e}") from e


def write_flow_exr(path: str | os.PathLike[str], flow: np.ndarray, valid: np.ndarray, sample_id: str) -> None:
    """Write :func:`encode_flow_exr`'s lossless (ZIP) bytes to ``path`` atomically (temp file + rename)."""
    write_atomic(Path(path), encode_flow_exr(flow, valid, sample_id))


def write_flo(path: str | os.PathLike[str], flow: np.ndarray, valid: np.ndarray | None = None) -> None:
    """Write a Middlebury ``.flo`` file atomically.

    Layout: float32 magic 202021.25 (the bytes ``PIEH``), int32 width, int32 height, then float32
    ``u, v`` interleaved row-major, all little-endian.

    Args:
        path: destination file.
        flow: ``(H, W, 2)`` floating array.
        valid: optional bool ``(H, W)``; invalid pixels are written as ``(1e10, 1e10)``, which
            Middlebury readers treat as unknown (> 1e9).

    Convention: flow projected -> captured, in px, ``flow[y, x] = (u, v)``.
    """
    path = Path(path)
    flow = _as_flow(flow, str(path))
    if valid is not None:
        flow = np.where(_as_valid(valid, flow.shape, str(path))[..., None], flow, np.float32(FLO_UNKNOWN))
    h, w = flow.shape[:2]
    write_atomic(path, struct.pack("<fii", FLO_MAGIC, w, h) + flow.astype("<f4").tobytes())


def read_flo(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Middlebury ``.flo`` file.

    Returns:
        flow float32 ``(H, W, 2)``; unknown pixels keep their stored values (> 1e9 by convention).

    Convention: flow projected -> captured, in px, ``flow[y, x] = (u, v)``.
    """
    path = Path(path)
    data = _read_bytes(path)
    if len(data) < 12 or struct.unpack_from("<f", data)[0] != FLO_MAGIC:
        raise ProjsynthError(f"{path}: not a Middlebury .flo file (bad magic); check the file")
    w, h = struct.unpack_from("<ii", data, 4)
    if w <= 0 or h <= 0 or len(data) != 12 + 8 * w * h:
        raise ProjsynthError(f"{path}: .flo header says {w}x{h} but has {len(data)} bytes; re-export it")
    return np.frombuffer(data, "<f4", offset=12).reshape(h, w, 2).astype(np.float32)
