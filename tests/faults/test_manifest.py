"""Defect 6: a manifest edited by hand, or a shard path that is a folder, is one line for every reader."""

import json

import pytest

import projreg.evaluation.methods
from projsynth.dataset.shards import shard_name

EDITS = {
    "shard_size 0": ({"shard_size": 0}, "shard_size is 0"),
    "shard_size a string": ({"shard_size": "8"}, "shard_size is '8'"),
    "num_samples -1": ({"num_samples": -1}, "num_samples is -1"),
    "size null": ({"size": None}, "size is None"),
    "size a string": ({"size": "96x128"}, "size is '96x128'"),
    "shards not a list": ({"shards": {"0": 1}}, "shards is"),
    "a count that is a string": ("count", "shards is"),
    "split edited": ({"split": "val"}, "does not hash to config_hash"),
    "seed edited": ({"seed": 5}, "does not hash to config_hash"),
}
COMMANDS = ["inspect", "export", "preview", "train", "bench"]


def _edit(root, change) -> None:
    path = root / "manifest.json"
    m = json.loads(path.read_text())
    if change == "count":
        m["shards"][1]["count"] = "8"
    else:
        m.update(change)
    path.write_text(json.dumps(m))


def _run(probe, command, root, tmp_path):
    if command == "train":
        options = "--steps 1 --batch-size 2 --crop none --workers 0 -q".split()
        return probe.projreg("train", "--data", root, "--out", tmp_path / "run", *options)
    if command == "bench":
        return probe.projreg("bench", "--data", root, "--baselines", "farneback", "-q")
    extra = {"inspect": [], "export": ["--out", tmp_path / "x", "-q"], "preview": ["--out", tmp_path / "p.png"]}
    return probe.projsynth(command, root, *extra[command])


@pytest.mark.parametrize("edit", EDITS)
def test_an_edited_manifest_is_one_line_for_readers_and_a_problem_for_verify(
    probe, d_copy, tmp_path, monkeypatch, edit
):
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)
    change, message = EDITS[edit]
    _edit(d_copy, change)
    manifest = d_copy / "manifest.json"
    for command in COMMANDS:
        probe.error(_run(probe, command, d_copy, tmp_path), manifest, message)
    assert not (tmp_path / "run").exists() and not (tmp_path / "p.png").exists() and not (tmp_path / "x").exists()
    line = probe.error(probe.projsynth("verify", d_copy, "-q"), manifest, message, code=1)
    assert line.startswith("projsynth: verify: ")


def test_a_shard_path_that_is_a_folder(probe, d_copy, tmp_path):
    shard = d_copy / shard_name(1)
    shard.unlink()
    shard.mkdir()
    probe.error(probe.projsynth("inspect", d_copy), shard, "cannot open shard")
    probe.error(probe.projsynth("verify", d_copy, "-q"), shard, "not a file", code=1)
    probe.error(probe.projsynth("export", d_copy, "--out", tmp_path / "x", "-q"), shard)
