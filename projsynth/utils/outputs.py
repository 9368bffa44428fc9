"""Where a command may write: never over one of its own inputs, nor into a folder of other files.

Every command that reads files and writes others checks, before it writes anything, that no output
(a file, or a folder it writes into) is one of its inputs. Identity is the file system's (device and
inode), so a link or another spelling of a path counts as the same file. A command that writes a
folder of its own files (``gen``, ``decode``) also refuses a folder holding files it does not write.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path

from ..errors import ProjsynthError

Named = tuple[str, Path | None]  # (option, path); None: not given


def _identity(path: Path | None) -> tuple[int, int] | None:
    if path is None:
        return None
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None  # not there (yet): no input, or reading it fails with its own message
    return st.st_dev, st.st_ino


def refuse_overwriting_inputs(outputs: Iterable[Named], inputs: Iterable[Named]) -> None:
    """Refuse an output that is one of the inputs, or two outputs that are one file.

    Args:
        outputs: ``(option, path)`` of each file (or folder) the command writes.
        inputs: ``(option, path)`` of each file (or folder) it reads.

    Raises:
        ProjsynthError: ``OPTION PATH: is the input OPTION PATH; write ... elsewhere``.
    """
    existing = {}
    for option, path in inputs:
        key = _identity(path)
        if key is not None:
            existing.setdefault(key, (option, path))
    seen: dict[Path, str] = {}
    for option, path in outputs:
        if path is None:
            continue
        hit = existing.get(_identity(path))
        if hit is not None:
            what = "folder" if Path(path).is_dir() else "file"
            raise ProjsynthError(f"{option} {path}: is the input {hit[0]} {hit[1]}; write the output to another {what}")
        resolved = Path(os.path.abspath(path))
        if resolved in seen and seen[resolved] != option:
            raise ProjsynthError(f"{option} {path}: also given as {seen[resolved]}; give each output its own file")
        seen[resolved] = option


def folder_files(option: str, folder: Path) -> list[Named]:
    """Every regular file directly inside ``folder`` (and the folder itself), as inputs named ``option``:
    a dataset's manifest and shards, a pattern set's PNGs."""
    folder = Path(folder)
    named: list[Named] = [(option, folder)]
    try:
        named += [(option, p) for p in sorted(folder.iterdir()) if p.is_file()]
    except OSError:
        pass  # a missing or unreadable folder is reported by its reader
    return named


def refuse_foreign_files(
    folder: Path, own: Callable[[str], bool], command: str, marks: tuple[str, ...] = (), option: str = "--out"
) -> None:
    """Refuse to write into ``folder`` when it holds an entry whose name ``own`` does not accept, or
    entries without one of ``marks`` (the names that only the command's own output has, if any).

    A new or empty folder passes, and so does the command's own earlier output (resumed or rewritten).
    Names that begin with a dot are not counted: what file managers hide (``.DS_Store``) and the
    command's own lock and temporaries (``.gen.lock``, ``.NAME.*.tmp``).

    Args:
        folder: the folder the command writes into (it may not exist yet).
        own: whether a name is one the command writes.
        command: the command, as the message names it (``projsynth gen``).
        marks: names of which the command's own folder holds at least one; () for none.
        option: the option that gave ``folder``.

    Raises:
        ProjsynthError: ``OPTION FOLDER: holds N file(s) not written by `COMMAND` (e.g. NAME); ...``.
    """
    folder = Path(folder)
    try:
        names = sorted(p.name for p in folder.iterdir() if not p.name.startswith(".")) if folder.is_dir() else []
    except OSError as e:
        raise ProjsynthError(f"{option} {folder}: cannot list it ({e.strerror or e}); check the folder") from None
    foreign = [n for n in names if not own(n)]
    if not foreign and marks and names and not set(marks) & set(names):
        foreign = names  # the command's names, but written by another (a `gen` dataset in `decode`'s way)
    if foreign:
        raise ProjsynthError(
            f"{option} {folder}: holds {len(foreign)} file(s) not written by `{command}` (e.g. {foreign[0]}); "
            f"choose a new or empty folder, or the folder of an earlier `{command}` (nothing was written)"
        )
