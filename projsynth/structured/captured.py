"""A dataset of captured pairs: pictures photographed on a real (or virtual) rig, with decoded truth.

``projsynth decode --pair PROJECTED CAPTURED`` turns each picture pair shot with the rig pose of the
pattern photos into one sample whose ground truth is the decoded correspondence (dense for
``graycode``, the dot centres for ``dots``). The result is an ordinary dataset (``dataset.json``,
shards, ``manifest.json``): ``verify``, ``inspect``, ``export``, ``preview``, ``projreg bench`` and
training read it like a generated one. What differs:

* the captured image has the camera's size, which may differ from the projected image's: the
  manifest's ``camera_size`` (``size`` stays the projector's); flows are in captured pixels;
* the plan records the capture instead of a generation config (``"captured"``: pattern kind and
  size, the sha256 of ``patterns.json``, of every pattern photo and of every pair's two files);
* sample ``k`` is ``captured-pKKKKK``, ``pair`` ``k``, role ``captured``, transform id -1 and
  transform family/condition ``captured`` (bench groups them under that name).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset.plan import Sample, plan_hash
from ..dataset.shards import (
    MANIFEST,
    PLAN_FILE,
    assemble_manifest,
    library_versions,
    read_json,
    shard_name,
    write_json_atomic,
    write_shard,
)
from ..errors import ProjsynthError
from ..utils.files import file_sha256
from ..utils.images import load_image
from ..versions import FORMAT_VERSION, __version__
from .patterns import PATTERNS_FILE, PatternSet

CAPTURED_ROLE = "captured"


def captured_samples(
    pairs: list[tuple[Path, Path]], flow: np.ndarray, valid: np.ndarray, camera_size: tuple[int, int]
) -> list[Sample]:
    """One sample per ``(projected, captured)`` file pair with the decoded ``flow``/``valid`` as truth.

    Raises:
        ProjsynthError: a picture is unreadable, the projected one is not the projector's size or the
            captured one not the photos' size.
    """
    h, w = valid.shape
    samples = []
    for k, (proj_path, cap_path) in enumerate(pairs):
        projected, captured = load_image(Path(proj_path)), load_image(Path(cap_path))
        if projected.shape[:2] != (h, w):
            raise ProjsynthError(
                f"--pair {proj_path}: {projected.shape[1]}x{projected.shape[0]} px, but the patterns "
                f"are {w}x{h}; the projected picture is the projector's frame buffer"
            )
        if captured.shape[:2] != tuple(camera_size):
            raise ProjsynthError(
                f"--pair {cap_path}: {captured.shape[1]}x{captured.shape[0]} px, but the pattern "
                f"photos are {camera_size[1]}x{camera_size[0]}; shoot both with one camera setting"
            )
        sid = f"captured-p{k:05d}"
        params = {
            "sample_id": sid,
            "pair": k,
            "role": CAPTURED_ROLE,
            "transform_id": -1,
            "transform": {
                "name": "captured",
                "family": "captured",
                "severity": 0,
                "condition": "captured",
                "table_version": None,
            },
            "sources": {
                "projected": Path(proj_path).name,
                "captured": Path(cap_path).name,
                "projected_sha256": file_sha256(proj_path),
                "captured_sha256": file_sha256(cap_path),
            },
            "camera_size": list(camera_size),
        }
        samples.append(Sample(k, sid, projected, captured, flow, valid, params))
    return samples


def require_captured_out(
    out: Path,
    patterns: PatternSet,
    patterns_dir: Path | None,
    photos: list[Path],
    samples: list[Sample],
    camera_size: tuple[int, int],
) -> dict:
    """The plan (``dataset.json``) of the dataset :func:`write_captured_dataset` writes, once ``out`` is
    found free for it: new, or holding this very dataset (the same config hash). Writes nothing, so that
    ``decode`` refuses before it touches its earlier output.

    Raises:
        ProjsynthError: ``out`` holds another dataset, an unreadable plan, or shards without a plan.
    """
    capture = {
        "patterns_kind": patterns.kind,
        "patterns_sha256": None if patterns_dir is None else file_sha256(Path(patterns_dir) / PATTERNS_FILE),
        "photos": [{"file": p.name, "sha256": file_sha256(p)} for p in photos],
        "pairs": [s.params["sources"] for s in samples],
    }
    info = {
        "format_version": FORMAT_VERSION,
        "generator": f"projsynth {__version__}",
        "size": list(patterns.size),
        "camera_size": list(camera_size),
        "seed": None,
        "split": "all",
        "pairs": len(samples),
        "transforms": None,
        "blend": "captured",
        "table_version": None,
        "captured": capture,
    }
    info["config_hash"] = plan_hash(info)
    info.update(shard_size=len(samples), num_shards=1, skipped_sources=[])
    plan_path = Path(out) / PLAN_FILE
    if plan_path.exists():
        if read_json(plan_path, "plan").get("config_hash") != info["config_hash"]:
            raise ProjsynthError(f"--out {out}: holds another dataset (see {plan_path}); use a new --out")
    elif (Path(out) / MANIFEST).exists() or any(Path(out).glob("shard-*.h5")):
        raise ProjsynthError(f"--out {out}: holds shards without {PLAN_FILE}; use an empty directory")
    return info


def write_captured_dataset(
    out: Path,
    patterns: PatternSet,
    patterns_dir: Path | None,
    photos: list[Path],
    samples: list[Sample],
    camera_size: tuple[int, int],
    plan: dict | None = None,
) -> dict:
    """Write ``samples`` as a one-shard dataset under ``out``; returns the manifest.

    ``patterns_dir`` None: the photos are in another tool's layout (``opencv-graycode``), with no
    ``patterns.json`` to hash. Re-running with the same inputs rewrites the same content; ``out``
    holding another dataset is refused (:func:`require_captured_out`). ``plan``: what
    :func:`require_captured_out` returned for these arguments, where the caller checked ``out`` first
    (the photos are not hashed again).
    """
    info = plan or require_captured_out(out, patterns, patterns_dir, photos, samples, camera_size)
    plan_path = Path(out) / PLAN_FILE
    try:
        Path(out).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out}: cannot create directory ({e.strerror}); choose a writable path") from e
    write_json_atomic(plan_path, info)
    attrs = {
        "format_version": FORMAT_VERSION,
        "generator": info["generator"],
        "config_hash": info["config_hash"],
        "seed": -1,
        "shard_index": 0,
        "first_sample": 0,
        "split": "all",
        "table_version": "captured",
        "libraries": library_versions(),
    }
    write_shard(Path(out) / shard_name(0), samples, attrs)
    return assemble_manifest(Path(out), info, 1, len(samples))
