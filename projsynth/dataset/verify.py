"""``projsynth verify`` and ``projsynth inspect``: check a dataset end to end, and summarise it."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..errors import ProjsynthError
from ..flow.formats import decode_flow_exr
from ..utils.files import file_sha256
from .manifest import manifest_problems
from .plan import Sample
from .shards import MANIFEST, ShardReader, open_shard, read_json, shard_name

BUCKETS = ("s0-10", "s10-40", "s40+")


def bucket_of(mag: np.ndarray) -> list[np.ndarray]:
    """Masks of the three flow-magnitude buckets (|gt| < 10, 10 <= |gt| <= 40, |gt| > 40)."""
    return [mag < 10.0, (mag >= 10.0) & (mag <= 40.0), mag > 40.0]


def _samples(path: Path) -> Iterator[tuple[int, Sample]]:
    with open_shard(path) as f:
        for i in range(int(f.attrs["count"])):
            flow, valid_exr, header = decode_flow_exr(f["flow_exr"][i].tobytes())
            valid = f["valid"][i]
            if not np.array_equal(valid, valid_exr):
                raise ValueError(f"sample {i}: EXR valid channel differs from the valid dataset")
            params = json.loads(f["params"][i])
            sid = f["sample_id"][i].decode()
            if header.get("sample_id") != sid:
                raise ValueError(f"sample {i}: EXR sample_id {header.get('sample_id')!r} is not {sid!r}")
            yield (
                i,
                Sample(int(f.attrs["first_sample"]) + i, sid, f["projected"][i], f["captured"][i], flow, valid, params),
            )


def verify(
    root: Path, progress: Callable[[int], None] | None = None, progress_total: Callable[[int], None] | None = None
) -> list[str]:
    """Check schema, hashes, finiteness and flow/valid consistency of every shard.

    ``progress_total(n)`` is called once the manifest is read (not before: a missing dataset is an
    error with no progress), ``progress(n)`` with each shard's samples.

    Returns:
        One line per problem, each naming the file (empty when the dataset is intact).
    """
    root = Path(root)
    path = root / MANIFEST
    manifest = read_json(path, "manifest")
    problems = [f"{path}: {p}; re-run `projsynth merge {root}`" for p in manifest_problems(manifest, path)]
    if problems:
        return problems  # the shard entries cannot be trusted to say which samples each file should hold
    h, w = manifest["size"]
    camera = tuple(manifest.get("camera_size") or (h, w))  # captured data: the camera's frame
    if progress_total:
        progress_total(sum(entry["count"] for entry in manifest["shards"]))
    for entry in manifest["shards"]:
        expected = iter(manifest["samples"][entry["first_sample"] : entry["first_sample"] + entry["count"]])
        path = root / entry["file"]
        if entry["file"] != shard_name(entry["index"]):
            problems.append(f"{path}: manifest names shard {entry['index']} {entry['file']!r}")
        if not path.is_file():
            what = "not a file" if path.exists() else "missing"
            problems.append(f"{path}: {what}; regenerate it with `projsynth gen ... --shards {entry['index']}`")
            continue
        try:
            if file_sha256(path) != entry["sha256"]:
                problems.append(f"{path}: sha256 differs from the manifest (corrupt or modified); regenerate it")
            problems += [f"{path}: {p}" for p in _check_shard(path, manifest, entry, expected, (h, w), camera)]
        except (OSError, KeyError, ValueError, ProjsynthError) as e:
            problems.append(f"{path}: unreadable ({e}); regenerate it")
        if progress:
            progress(entry["count"])
    return problems


def _check_shard(
    path: Path, manifest: dict, entry: dict, expected: Iterator, size: tuple[int, int], camera: tuple[int, int]
) -> list[str]:
    (h, w), (hc, wc) = size, camera
    out = []
    with open_shard(path) as f:
        n = entry["count"]
        a = f.attrs
        if (
            a.get("config_hash") != manifest["config_hash"]
            or a.get("shard_index") != entry["index"]
            or a.get("first_sample") != entry["first_sample"]
            or a.get("count") != n
            or a.get("format_version") != manifest.get("format_version")
            or a.get("generator") != manifest.get("generator")
        ):
            out.append(
                "attributes do not match the manifest (config hash, shard index, first sample, count, "
                "format version or generator)"
            )
        for name, shape in (("projected", (n, h, w, 3)), ("captured", (n, hc, wc, 3)), ("valid", (n, h, w))):
            if f[name].shape != shape:
                out.append(f"dataset {name} has shape {f[name].shape}, expected {shape}")
        if out:
            return out
        stored = [s.decode() for s in f["sample_hash"][:]]
    ys, xs = np.mgrid[0:h, 0:w]
    for i, s in _samples(path):
        want = next(expected, {"id": None, "sha256": None})
        digest = s.content_hash()
        if digest != stored[i] or digest != want["sha256"] or s.id != want["id"]:
            out.append(f"sample {i} ({s.id}): content hash differs from the manifest")
        if not np.isfinite(s.flow).all():
            out.append(f"sample {i} ({s.id}): flow has NaN or Inf")
            continue
        if np.any(s.flow[~s.valid] != 0):
            out.append(f"sample {i} ({s.id}): non-zero flow at invalid pixels")
        u, v = xs + s.flow[..., 0], ys + s.flow[..., 1]
        e = 1e-3  # float32 storage of the flow
        inside = (u >= -e) & (u <= wc - 1 + e) & (v >= -e) & (v <= hc - 1 + e)
        if np.any(s.valid & ~inside):
            out.append(f"sample {i} ({s.id}): valid pixels whose flow leaves the camera frame")
    return out


_CONFIG_KEYS = ("size", "camera_size", "seed", "split", "pairs", "blend", "table_version")


HIST_EDGES = (0, 2, 5, 10, 20, 40, 80, 160, np.inf)


def inspect(
    root: Path, progress: Callable[[int], None] | None = None, progress_total: Callable[[int], None] | None = None
) -> dict:
    """Counts, per-family flow-magnitude histograms and the share of valid pixels per bucket.

    ``progress_total(n)`` is called once the dataset is open, ``progress(1)`` after each sample.
    """
    root = Path(root)
    reader = ShardReader(root)
    manifest = reader.manifest
    edges = list(HIST_EDGES)
    if progress_total:
        progress_total(len(reader))
    families: dict[str, dict] = {}
    total = {"samples": 0, "pixels": 0, "valid": 0, "buckets": [0, 0, 0], "hist": [0] * (len(edges) - 1)}
    try:
        for k in range(len(reader)):
            s = reader.read(k)
            fam, flow, valid = s["params"]["transform"]["family"], s["flow"], s["valid"]
            rec = families.setdefault(
                fam, {"samples": 0, "pixels": 0, "valid": 0, "buckets": [0, 0, 0], "hist": [0] * (len(edges) - 1)}
            )
            mag = np.hypot(flow[..., 0], flow[..., 1])[valid]
            counts = [int(m.sum()) for m in bucket_of(mag)]
            hist = np.histogram(mag, bins=edges)[0]
            for r in (rec, total):
                r["samples"] += 1
                r["pixels"] += valid.size
                r["valid"] += int(valid.sum())
                r["buckets"] = [a + b for a, b in zip(r["buckets"], counts, strict=True)]
                r["hist"] = [a + int(b) for a, b in zip(r["hist"], hist, strict=True)]
            if progress:
                progress(1)
    finally:
        reader.close()
    return {
        "dataset": str(root),
        "config": {k: manifest[k] for k in _CONFIG_KEYS if k in manifest},
        "total": _summary(total),
        "families": {k: _summary(v) for k, v in sorted(families.items())},
        "histogram_edges_px": [e if np.isfinite(e) else None for e in edges],
        "config_hash": manifest["config_hash"],
    }


def _summary(r: dict) -> dict:
    valid = max(r["valid"], 1)
    return {
        "samples": r["samples"],
        "valid_share": round(r["valid"] / max(r["pixels"], 1), 4),
        "bucket_share": {name: round(c / valid, 4) for name, c in zip(BUCKETS, r["buckets"], strict=True)},
        "histogram": r["hist"],
    }
