"""Shards on disk: atomic HDF5 writing, reading one sample back, the manifest, and verification.

A dataset directory holds ``dataset.json`` (the plan), ``shard-NNNNN.h5`` files and, once every shard
exists, ``manifest.json`` (per-shard sha256 and per-sample content hashes). See docs/format.md.
"""

from __future__ import annotations

import errno
import io
import json
import os
import re
import threading
import zlib
from pathlib import Path

import h5py
import numpy as np

from ..errors import ProjsynthError
from ..flow.formats import decode_flow_exr, encode_flow_exr
from ..utils.files import file_sha256, write_atomic
from .manifest import manifest_problems
from .plan import Sample

MANIFEST, PLAN_FILE = "manifest.json", "dataset.json"
# Format 2: HDF5's Fletcher-32 checksum on every chunk of every fixed-size dataset, so a damaged chunk
# fails its read; HDF5 cannot filter variable-length data, so those datasets (CRC_COLUMNS) get a CRC-32
# per sample in ``crc32`` instead, which the readers check.
_TABLE_OPTS = {"fletcher32": True, "track_times": False}
_IMAGE_OPTS = {"compression": "lzf", **_TABLE_OPTS}
CRC_COLUMNS = ("flow_exr", "sample_id", "params", "sample_hash")
# what HDF5's "filter returned failure during read" means for a shard
_DAMAGED_CHUNK = "damaged: a chunk fails its Fletcher-32 checksum or does not decompress"


def shard_name(index: int) -> str:
    return f"shard-{index:05d}.h5"


_SHARD_FILE = re.compile(r"shard-\d{5,}\.h5(\.tmp)?")  # a shard, or the temporary of one being written


def is_dataset_file(name: str) -> bool:
    """Whether ``name`` is one a dataset directory holds: the plan, the manifest, a shard, or the
    temporary a killed run left of a shard."""
    return name in (PLAN_FILE, MANIFEST) or _SHARD_FILE.fullmatch(name) is not None


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON to ``path`` atomically (a private temporary name, fsync, rename): concurrent writers
    of a job array never see or publish a mix."""
    write_atomic(path, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())


def _why(e: OSError) -> str:
    if e.errno == errno.ENOSPC:
        return "no space left on device; free space and re-run the same command to resume"
    if e.errno == errno.EFBIG:
        return "file too large for this file system or process limit; use a smaller --shard-size"
    return f"{e.strerror or e}; check the directory is writable"


def open_shard(path: Path) -> h5py.File:
    """Open a finished shard for reading; a missing or unreadable file is one ProjsynthError naming it."""
    try:
        return h5py.File(path, "r")
    except (OSError, ValueError) as e:
        why = os.strerror(e.errno) if getattr(e, "errno", None) else " ".join(str(e).split())  # HDF5's spans lines
        raise ProjsynthError(f"{path}: cannot open shard ({why}); run `projsynth verify` and regenerate it") from e


def write_shard(path: Path, samples: list[Sample], attrs: dict) -> None:
    """Write ``samples`` as one shard, atomically: a temporary file, fsync, then rename.

    HDF5 builds the file in memory and Python writes it out, so a full disk or an unwritable directory
    is an ordinary OSError: HDF5 never holds a file whose writes failed (on disk, its objects outlived
    the failed close and crashed the interpreter at exit). Whatever stops the write, the
    temporary file is removed and no ``shard-NNNNN.h5`` appears.

    Raises:
        ProjsynthError: the disk is full or the directory unwritable.
    """
    tmp = path.with_name(path.name + ".tmp")
    image = _shard_image(samples, attrs)
    try:
        with open(tmp, "wb") as fh:
            fh.write(image)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as e:
        raise ProjsynthError(f"{path}: cannot write shard ({_why(e)})") from e
    finally:
        tmp.unlink(missing_ok=True)


def _shard_image(samples: list[Sample], attrs: dict) -> memoryview:
    """The bytes of a shard file holding ``samples``, built in a ``BytesIO`` (nothing touches the disk;
    unlike HDF5's core driver and ``get_file_image``, no second copy of the file is made)."""
    buf = io.BytesIO()
    with h5py.File(buf, "w", libver="v110", track_order=False) as f:
        _fill(f, samples, attrs)
    return buf.getbuffer()


def _fill(f: h5py.File, samples: list[Sample], attrs: dict) -> None:
    """The datasets and attributes of a shard (docs/format.md, format 2)."""
    n = len(samples)
    h, w = samples[0].projected.shape[:2]
    hc, wc = samples[0].captured.shape[:2]  # the camera's frame may differ from the projector's (captured data)
    for key, value in attrs.items():
        f.attrs[key] = value
    f.attrs["count"] = n
    proj = f.create_dataset("projected", (n, h, w, 3), np.uint8, chunks=(1, h, w, 3), **_IMAGE_OPTS)
    capt = f.create_dataset("captured", (n, hc, wc, 3), np.uint8, chunks=(1, hc, wc, 3), **_IMAGE_OPTS)
    valid = f.create_dataset("valid", (n, h, w), bool, chunks=(1, h, w), **_IMAGE_OPTS)
    exr = f.create_dataset("flow_exr", (n,), h5py.vlen_dtype(np.uint8), track_times=False)
    shared = None  # (frame, its compressed chunk): the samples of a pair and role share the frame
    blobs = []
    for i, s in enumerate(samples):
        if shared is not None and s.projected is shared[0]:
            # the raw chunk carries its Fletcher-32 checksum, which holds for the same bytes anywhere
            proj.id.write_direct_chunk((i, 0, 0, 0), shared[2], filter_mask=shared[1])
        else:
            proj[i] = s.projected
            proj.flush()  # out of HDF5's chunk cache: a direct read of a cached chunk failed here (48 x 64)
            shared = (s.projected, *proj.id.read_direct_chunk((i, 0, 0, 0)))
        capt[i], valid[i] = s.captured, s.valid
        blobs.append(encode_flow_exr(s.flow, s.valid, s.id))
        exr[i] = np.frombuffer(blobs[-1], np.uint8)
    text = h5py.string_dtype()
    columns = {
        "flow_exr": blobs,
        "sample_id": [s.id for s in samples],
        "params": [json.dumps(s.params, sort_keys=True) for s in samples],
        "sample_hash": [s.content_hash() for s in samples],
    }
    for name in CRC_COLUMNS[1:]:
        f.create_dataset(name, data=columns[name], dtype=text, track_times=False)
    f.create_dataset("transform_id", data=[s.params["transform_id"] for s in samples], dtype=np.int16, **_TABLE_OPTS)
    crc = [
        [zlib.crc32(v if isinstance(v, bytes) else v.encode()) for v in row]
        for row in zip(*(columns[name] for name in CRC_COLUMNS), strict=True)
    ]
    f.create_dataset("crc32", data=np.array(crc, np.uint32), **_TABLE_OPTS).attrs["columns"] = ",".join(CRC_COLUMNS)
    f.attrs["complete"] = True


def library_versions() -> str:
    """The builds that shape a sample's bytes, as canonical JSON (a shard's ``libraries`` attribute).

    Samples are a pure function of the config and seed for one set of these; another numpy, OpenCV
    or numba may round differently, so ``gen`` records them instead of hashing them into the config
    (a resume after an upgrade stays possible, and the manifest shows the mix).
    """
    import platform

    import cv2
    import numba
    import OpenEXR

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "numba": numba.__version__,
        "h5py": h5py.__version__,
        "openexr": OpenEXR.__version__,
    }
    return json.dumps(versions, sort_keys=True)


def shard_is_complete(path: Path, config_hash: str) -> bool:
    """True when ``path`` is a finished shard of the dataset with ``config_hash``."""
    try:
        with h5py.File(path, "r") as f:
            return bool(f.attrs.get("complete")) and f.attrs.get("config_hash") == config_hash
    except (OSError, ValueError):
        return False


def assemble_manifest(root: Path, plan_info: dict, num_shards: int, shard_size: int) -> dict:
    """Build and write ``manifest.json`` from the finished shards under ``root``."""
    shards, samples, builds = [], [], set()
    for j in range(num_shards):
        path = root / shard_name(j)
        with h5py.File(path, "r") as f:
            ids = [s.decode() for s in f["sample_id"][:]]
            hashes = [s.decode() for s in f["sample_hash"][:]]
            if "libraries" in f.attrs:  # (not written before 0.2.0)
                builds.add(f.attrs["libraries"])
        shards.append(
            {
                "index": j,
                "file": path.name,
                "first_sample": j * shard_size,
                "count": len(ids),
                "sha256": file_sha256(path),
                "bytes": path.stat().st_size,
            }
        )
        samples += [{"id": i, "sha256": s} for i, s in zip(ids, hashes, strict=True)]
    manifest = {
        **plan_info,
        "shard_size": shard_size,
        "num_samples": len(samples),
        "shards": shards,
        "libraries": [json.loads(b) for b in sorted(builds)],
        "samples": samples,
    }
    write_json_atomic(root / MANIFEST, manifest)
    return manifest


def read_json(path: Path, what: str) -> dict:
    """A JSON object from ``path``; any problem is one ProjsynthError naming the file."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ProjsynthError(f"{path}: no {what}; is this a projsynth dataset (finished `gen` or `merge`)?") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ProjsynthError(f"{path}: unreadable {what} ({e}); regenerate it") from e
    if not isinstance(data, dict):
        raise ProjsynthError(f"{path}: not a {what} (expected a JSON object); regenerate it")
    return data


def load_manifest(root: Path) -> dict:
    """The manifest of dataset ``root``, refused (one ProjsynthError naming it) unless
    :func:`manifest.manifest_problems` finds it sound."""
    path = Path(root) / MANIFEST
    manifest = read_json(path, "manifest")
    problems = manifest_problems(manifest, path)
    if problems:
        raise ProjsynthError(
            f"{path}: {problems[0]}; run `projsynth verify {root}`, or rebuild the manifest "
            f"with `projsynth merge {root}`"
        )
    return manifest


class ShardReader:
    """Random access to the samples of one dataset directory; HDF5 files open lazily, per process.

    Convention: ``read(k)`` returns projected/captured ``(H, W, 3)`` uint8, flow ``(H, W, 2)``
    float32 projected->captured, valid ``(H, W)`` bool, and the parameter dict.
    """

    def __init__(self, root: Path, max_open: int = 64):
        """``max_open``: HDF5 files kept open per process; the least recently read is closed first, so
        a pass over a dataset of any size stays within the process's file-descriptor limit."""
        self.root = Path(root)
        self.manifest = load_manifest(self.root)
        self.shard_size = self.manifest["shard_size"]
        self.max_open = max(1, max_open)
        self._files: dict[int, h5py.File] = {}  # in order of last use
        self._crc: dict[int, np.ndarray | None] = {}  # each opened shard's crc32 dataset (format 2)
        self._pid = os.getpid()

    def __len__(self) -> int:
        return self.manifest["num_samples"]

    def _file(self, j: int) -> h5py.File:
        if self._pid != os.getpid():  # never share HDF5 handles across a fork
            self._files, self._pid = {}, os.getpid()
        f = self._files.pop(j, None)
        if f is None:
            if len(self._files) >= self.max_open:
                self._files.pop(next(iter(self._files))).close()
            f = self._open(j)
        self._files[j] = f  # now the most recently used
        return f

    def _open(self, j: int) -> h5py.File:
        """Shard ``j``, refused unless its attributes place it where the manifest says (a shard copied in
        from another dataset, or renamed, would otherwise be read as this one's); keeps its ``crc32``."""
        path, entry = self.root / shard_name(j), self.manifest["shards"][j]
        f = open_shard(path)
        try:
            a = f.attrs
            mine = (
                a.get("config_hash") == self.manifest["config_hash"]
                and a.get("first_sample") == entry["first_sample"]
                and a.get("count") == entry["count"]
            )
            self._crc[j] = f["crc32"][:] if "crc32" in f else None  # format 1 shards have none
        except (OSError, KeyError, ValueError) as e:
            f.close()
            why = _DAMAGED_CHUNK if "filter returned failure" in str(e) else " ".join(str(e).split())
            raise ProjsynthError(f"{path}: unreadable header ({why}); run `projsynth verify {self.root}`") from e
        if not mine:
            f.close()
            raise ProjsynthError(
                f"{path}: not this dataset's shard {j} (its config hash, first sample or count "
                f"differ from {self.root / MANIFEST}); run `projsynth verify {self.root}` "
                "and regenerate it"
            )
        return f

    def read(self, k: int, with_params: bool = True, flow_exr: bool = False) -> dict:
        """Sample ``k``; ``with_params=False`` skips parsing the parameter JSON (training needs none),
        ``flow_exr=True`` adds the stored EXR file's bytes, unchanged (``export``).

        ``valid`` comes from the flow EXR (``verify`` checks it equals the ``valid`` dataset). The EXR
        decodes on a short-lived thread (OpenEXR releases the GIL) while the two images decompress here:
        about 1 ms more CPU time, about a third less latency (docs/history/2026-11-log.md). No thread outlives
        the call, so forking (DataLoader workers) is always safe. Format 2: HDF5 verifies each image
        chunk's Fletcher-32 checksum; the EXR's CRC-32 is checked on the decoding thread, the
        parameters' here (docs/format.md).
        """
        if not 0 <= k < len(self):
            raise IndexError(k)
        j, i = divmod(k, self.shard_size)
        f = self._file(j)
        try:
            crc = None if self._crc[j] is None else self._crc[j][i]
            exr = f["flow_exr"][i].tobytes()
            decoding = _Decoding(exr, crc)
            try:
                out = {"projected": f["projected"][i], "captured": f["captured"][i]}
            finally:
                decoding.join()  # also when an image read fails: the thread ends with the call
            flow, valid = decoding.result()
            out.update(valid=valid, flow=flow)
            if flow_exr:
                out["flow_exr"] = exr
            if with_params:
                out["params"] = json.loads(_checked(f["params"][i], crc, "params"))
            return out
        except (OSError, KeyError, ValueError, ProjsynthError) as e:
            why = _DAMAGED_CHUNK if "filter returned failure" in str(e) else e
            raise ProjsynthError(
                f"{self.root / shard_name(j)}: sample {i} unreadable ({why}); run `projsynth verify {self.root}`"
            ) from e

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files = {}


def _checked(data: bytes, crc: np.ndarray | None, column: str) -> bytes:
    """``data`` (a sample's bytes of the variable-length dataset ``column``) if its CRC-32 matches ``crc``
    (the sample's row of the ``crc32`` dataset; None: a format 1 shard, nothing to check)."""
    if crc is not None and zlib.crc32(data) != int(crc[CRC_COLUMNS.index(column)]):
        raise ValueError(f"{column} fails its CRC-32 (corrupt)")
    return data


class _Decoding(threading.Thread):
    """The CRC check (``crc``: the sample's ``crc32`` row, or None) and :func:`decode_flow_exr` of
    ``data`` on its own thread (both release the GIL); ``result()`` joins it and returns
    ``(flow, valid)`` or raises what the check or the decoder raised."""

    def __init__(self, data: bytes, crc: np.ndarray | None):
        super().__init__(name="exr-decode", daemon=True)
        self._data, self._crc, self._out, self._error = data, crc, None, None
        self.start()

    def run(self) -> None:
        try:
            self._out = decode_flow_exr(_checked(self._data, self._crc, "flow_exr"))[:2]
        except BaseException as e:  # re-raised in the caller's thread
            self._error = e

    def result(self) -> tuple:
        self.join()
        if self._error is not None:
            raise self._error
        return self._out
