"""What a well-formed ``manifest.json`` is: its schema, its arithmetic and its config hash, in one place.

Every reader (``ShardReader``: ``inspect``, ``export``, ``preview``, ``train``, ``bench``) refuses a
manifest with problems through :func:`shards.load_manifest`; ``verify`` reports them all. A manifest
edited by hand therefore never reaches arithmetic on a string or a division by zero, and an edit of a
plan field (``split``, ``seed``, ``size`` ...) shows as a mismatch with ``config_hash``.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

from ..content.sources import SPLITS
from ..errors import ProjsynthError
from ..sim.motion import MOTIONS
from ..versions import READABLE_FORMATS
from .plan import CAPTURED_PLAN_KEYS, MAX_FRAMES, MAX_SIZE, MIN_SIZE, PLAN_KEYS, SEQUENCE_KEYS, plan_hash


def _int(lo: int) -> Callable[[object], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _text(v: object) -> bool:
    return isinstance(v, str)


def _sha256(v: object) -> bool:
    return isinstance(v, str) and re.fullmatch("[0-9a-f]{64}", v) is not None


def _list_of(check: Callable[[object], bool], nonempty: bool = True) -> Callable[[object], bool]:
    return lambda v: isinstance(v, list) and (bool(v) or not nonempty) and all(check(x) for x in v)


def _entry(fields: dict[str, Callable[[object], bool]]) -> Callable[[object], bool]:
    return lambda v: isinstance(v, dict) and all(k in v and check(v[k]) for k, check in fields.items())


def _sources(v: object) -> bool:
    return v is None or (isinstance(v, dict) and all(_list_of(_text)(names) for names in v.values()))


# key -> (check, what it must be); extra keys are allowed (later versions add some)
_SCHEMA: dict[str, tuple[Callable[[object], bool], str]] = {
    "generator": (_text, "a string"),
    "config_hash": (_sha256, "a sha256 hex digest"),
    "size": (
        lambda v: _list_of(_int(MIN_SIZE))(v) and len(v) == 2 and max(v) <= MAX_SIZE,
        f"[H, W] with each side in {MIN_SIZE}..{MAX_SIZE}",
    ),
    "seed": (_int(0), "an integer >= 0"),
    "split": (lambda v: v in SPLITS, f"one of {', '.join(SPLITS)}"),
    "pairs": (_int(1), "an integer >= 1"),
    "transforms": (_list_of(_int(0)), "a non-empty list of transform ids"),
    "blend": (_text, "a string"),
    "table_version": (_text, "a string"),
    "table_digest": (_text, "a string"),
    "sources": (_sources, "null or {kind: [names]}"),
    "shard_size": (_int(1), "an integer >= 1"),
    "num_samples": (_int(1), "an integer >= 1"),
    "shards": (
        _list_of(
            _entry({"index": _int(0), "file": _text, "first_sample": _int(0), "count": _int(1), "sha256": _sha256})
        ),
        "a non-empty list of {index, file, first_sample, count >= 1, sha256}",
    ),
    "samples": (_list_of(_entry({"id": _text, "sha256": _sha256})), "a non-empty list of {id, sha256}"),
}


# Sequence datasets only (``frames`` > 1); a manifest without them is a single-frame one.
_SEQUENCE_SCHEMA: dict[str, tuple[Callable[[object], bool], str]] = {
    "frames": (lambda v: _int(2)(v) and v <= MAX_FRAMES, f"an integer in 2..{MAX_FRAMES}"),
    "motion": (lambda v: v in MOTIONS, f"one of {', '.join(MOTIONS)}"),
}

# A captured dataset (projsynth.structured.captured): no generation config, a capture record and the camera's size.
_CAPTURED_SCHEMA = {
    k: v for k, v in _SCHEMA.items() if k not in ("seed", "transforms", "table_version", "table_digest", "sources")
}
_CAPTURED_SCHEMA["camera_size"] = (_SCHEMA["size"][0], _SCHEMA["size"][1])
_CAPTURED_SCHEMA["captured"] = (lambda v: isinstance(v, dict), "the capture record {patterns_kind, photos, pairs}")


def manifest_problems(m: dict, path: Path) -> list[str]:
    """Everything wrong with the manifest ``m`` read from ``path``, one line each; empty when sound.

    A file that is no manifest this version reads (another format version, keys missing) raises;
    damage is returned, checked in order and stopping at the first group with problems: every key's
    type (``_SCHEMA``); the arithmetic (shards ``0..N-1`` in order, each holding ``shard_size``
    samples but the last, tiling ``num_samples``, which equals the samples listed and
    ``pairs x 2 x len(transforms)``); and that the plan fields hash to ``config_hash``.

    Raises:
        ProjsynthError: naming ``path``, when ``m`` is not a manifest of a readable format.
    """
    version = m.get("format_version")
    if version not in READABLE_FORMATS:
        raise ProjsynthError(
            f"{path}: format version {version!r} is not one this projsynth reads "
            f"({', '.join(map(str, READABLE_FORMATS))}); use the projsynth that wrote it"
        )
    schema = _CAPTURED_SCHEMA if "captured" in m else _SCHEMA
    if any(k in m for k in SEQUENCE_KEYS):
        schema = schema | _SEQUENCE_SCHEMA
    missing = [k for k in schema if k not in m]
    if missing:
        raise ProjsynthError(f"{path}: manifest lacks {', '.join(missing)}; re-run `projsynth merge {path.parent}`")
    wrong = [f"{k} is {m[k]!r:.60}, expected {what}" for k, (check, what) in schema.items() if not check(m[k])]
    if wrong:
        return wrong
    return _layout_problems(m) or _hash_problems(m)


def _layout_problems(m: dict) -> list[str]:
    size, shards, out = m["shard_size"], m["shards"], []
    if "num_shards" in m and m["num_shards"] != len(shards):
        out.append(f"lists {len(shards)} shards, num_shards says {m['num_shards']}")
    first = 0
    for j, e in enumerate(shards):
        if e["index"] != j or e["first_sample"] != first:
            out.append(f"shard entry {j} is not shard {j} starting at sample {first}")
            break
        if m.get("frames", 1) > 1 and (e["count"] % m["frames"] or size % m["frames"]):
            out.append(
                f"shard {j} holds {e['count']} samples of shards of {size}: not whole sequences of {m['frames']} frames"
            )
        if e["count"] > size or (e["count"] < size and j < len(shards) - 1):
            out.append(f"shard {j} holds {e['count']} samples; every shard but the last holds {size}")
        first += e["count"]
    planned = (
        ("captured pairs are", m["pairs"])
        if "captured" in m
        else (
            "plan (pairs x 2 x transforms x frames) makes",
            m["pairs"] * 2 * len(m["transforms"]) * m.get("frames", 1),
        )
    )
    for what, n in (("shard counts sum to", first), ("samples list has", len(m["samples"])), planned):
        if n != m["num_samples"]:
            out.append(f"num_samples is {m['num_samples']} but the {what} {n}")
    return out


def _hash_problems(m: dict) -> list[str]:
    if plan_hash(m) == m["config_hash"]:
        return []
    keys = (CAPTURED_PLAN_KEYS if "captured" in m else PLAN_KEYS) + (SEQUENCE_KEYS if "frames" in m else ())
    return [f"the plan ({', '.join(keys)}) does not hash to config_hash: edited after it was written"]
