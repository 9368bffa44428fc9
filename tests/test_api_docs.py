"""docs/api.md runs as written: every ``python`` block, in order, in one namespace (a block that raises
fails the test)."""

import re
from pathlib import Path

import pytest

API = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def test_every_example_of_the_api_page_runs(tmp_path, monkeypatch, capsys):
    pytest.importorskip("skimage.data")
    blocks = re.findall(r"```python\n(.*?)```", API.read_text(), re.S)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"{API}:block{i}", "exec"), namespace)  # noqa: S102 - the page's own examples
    out = capsys.readouterr().out
    assert "True (384, 512, 2) float32 (384, 512)" in out
    assert "expected a uint8 RGB array" in out and "expected one of fast, balanced, accurate" in out
    assert namespace["steps"][0] == "full" and len(namespace["steps"]) == 3
    assert re.search(r"^4 \(64, 96, 2\) \S+ False$", out, re.M), out  # a dataset read without torch
    assert namespace["match"].valid.mean() > 0.5
