"""Tiny shards made by projsynth itself: the fixtures of every projreg test."""

import pytest

from projsynth.dataset import resolve_plan
from projsynth.generate import generate


def make_shards(root, *, size=(64, 96), transforms="0,21,42,63,84,105,126,147", seed=0, split="train"):
    plan = resolve_plan(size=size, seed=seed, split=split, pairs=1, transforms=transforms, blend="paper")
    generate(plan, root, shard_size=8)
    return root


@pytest.fixture(scope="session")
def tiny_train(tmp_path_factory):
    return make_shards(tmp_path_factory.mktemp("tiny") / "train")


@pytest.fixture(scope="session")
def tiny_val(tmp_path_factory):
    return make_shards(tmp_path_factory.mktemp("tiny") / "val", split="val", transforms="10,90")
