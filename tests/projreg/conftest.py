"""Tiny shards made by projsynth itself: the fixtures of every projreg test."""

import pytest

from projreg.training.train import TrainConfig, train
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import resolve_plan
from projsynth.dataset.shards import ShardReader


def make_shards(root, *, size=(64, 96), transforms="0,21,42,63,84,105,126,147", seed=0, split="train", blend="paper"):
    plan = resolve_plan(size=size, seed=seed, split=split, pairs=1, transforms=transforms, blend=blend)
    generate(plan, root, shard_size=8)
    return root


@pytest.fixture(scope="session")
def tiny_train(tmp_path_factory):
    return make_shards(tmp_path_factory.mktemp("tiny") / "train")


@pytest.fixture(scope="session")
def tiny_physical(tmp_path_factory):
    """Six samples of the physical blend (ambient light on a textured surface, gamma, defocus, noise)."""
    return make_shards(
        tmp_path_factory.mktemp("tiny") / "physical", transforms="2,47,128", seed=4, split="test", blend="physical"
    )


@pytest.fixture(scope="session")
def small_physical(tmp_path_factory):
    """:func:`tiny_physical`'s samples at 128 x 160: a frame of 64 x 96 holds about ten of the checks' windows,
    too few for a claim to be told from chance (``confidence.registered_windows``), so what needs
    registered pairs is measured on these."""
    return make_shards(
        tmp_path_factory.mktemp("small") / "physical",
        size=(128, 160),
        transforms="2,47,128",
        seed=4,
        split="test",
        blend="physical",
    )


@pytest.fixture(scope="session")
def tiny_val(tmp_path_factory):
    return make_shards(tmp_path_factory.mktemp("tiny") / "val", split="val", transforms="10,90")


@pytest.fixture(scope="session")
def tiny_sequences(tmp_path_factory):
    """Four sequences of 3 frames (two transforms x two roles) of a hovering projector, 64 x 96."""
    plan = resolve_plan(
        size=(64, 96), seed=2, split="test", pairs=1, transforms="0,126", blend="paper", frames=3, motion="hover"
    )
    root = tmp_path_factory.mktemp("tiny") / "sequences"
    generate(plan, root, shard_size=6)
    return root


@pytest.fixture(scope="session")
def tiny_ckpt(tiny_train, tmp_path_factory):
    """A 2-step checkpoint: weights are untrained, the plumbing is real."""
    out = tmp_path_factory.mktemp("run") / "run"
    train(TrainConfig(data=[str(tiny_train)], out=str(out), steps=2, batch_size=1, workers=0, crop=None))
    return out / "checkpoints" / "last.pt"


def _assert_one_line_error(result, *needles):
    assert result.exit_code == 2, (result.exit_code, result.stderr, result.exception)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("projreg: error: "), lines
    for needle in needles:
        assert str(needle) in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture
def one_line_error():
    """Check a CliRunner result failed with exit 2 and one ``projreg: error:`` line naming ``needles``."""
    return _assert_one_line_error


@pytest.fixture(scope="session")
def pairs(tiny_train):
    """Two shard samples as (projected, captured) RGB arrays."""
    reader = ShardReader(tiny_train)
    try:
        return [(s["projected"], s["captured"]) for s in (reader.read(0), reader.read(13))]
    finally:
        reader.close()
