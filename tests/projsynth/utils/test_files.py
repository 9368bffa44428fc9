"""Files written whole or not at all (``projsynth.utils.files``)."""

import pytest

from projsynth import ProjsynthError
from projsynth.utils.files import write_atomic_all


def test_write_atomic_all_writes_every_file_or_none(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"a file where a folder is needed")
    good, bad = tmp_path / "sub" / "a.json", blocker / "b.md"
    with pytest.raises(ProjsynthError, match=rf"^{bad}: cannot write"):
        write_atomic_all([(good, b"first"), (bad, b"second")], make_parents=True)
    assert not good.exists() and [p.name for p in (tmp_path / "sub").iterdir()] == []  # no temporary left
    with pytest.raises(ProjsynthError, match="new"):  # folders are made only when asked
        write_atomic_all([(tmp_path / "new" / "x", b"")])
    write_atomic_all([(good, b"first"), (tmp_path / "c.md", b"second")])
    assert good.read_bytes() == b"first" and (tmp_path / "c.md").read_bytes() == b"second"
