"""Files written whole or not at all (a temporary name, fsync, rename), and their hashes."""

from __future__ import annotations

import hashlib
import os
import secrets
from pathlib import Path

from ..errors import ProjsynthError


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary name in the same directory, fsync, then rename: no half-written file."""
    write_atomic_all([(path, data)])


def write_atomic_all(files: list[tuple[Path, bytes]], make_parents: bool = False) -> None:
    """Write several files all or nothing: every one to a temporary name (fsync) first, then rename
    them; if any cannot be written, the temporaries are removed and no destination is touched.
    ``make_parents`` creates missing folders (otherwise a missing folder is an error).

    Raises:
        ProjsynthError: naming the file that could not be written (or created as a folder).
    """
    staged: list[tuple[Path, Path]] = []
    try:
        for path, data in files:
            path = Path(path)
            tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
            try:
                if make_parents:
                    path.parent.mkdir(parents=True, exist_ok=True)
                with open(tmp, "xb") as f:
                    staged.append((tmp, path))
                    f.write(data)
                    f.flush()
                    os.fsync(f.fileno())
            except OSError as e:
                raise ProjsynthError(f"{path}: cannot write ({e.strerror or e}); check the directory") from e
        for tmp, path in staged:
            try:
                os.replace(tmp, path)
            except OSError as e:
                raise ProjsynthError(f"{path}: cannot write ({e.strerror or e}); check the directory") from e
    finally:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)


def remove_stale_temporaries(folder: Path, names: list[str]) -> None:
    """Remove the temporaries ``.NAME.*.tmp`` that an interrupted :func:`write_atomic_all` of ``NAME``
    in ``folder`` left behind. Only for a folder one command writes alone (not a job array's manifest:
    another writer's temporary may be in flight there)."""
    for name in names:
        for tmp in Path(folder).glob(f".{name}.*.tmp"):
            tmp.unlink(missing_ok=True)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
