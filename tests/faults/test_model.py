"""Defect 10: a checkpoint's ``model_config`` is bounded before any model is built from it."""

import cv2
import numpy as np
import pytest
import torch

import projreg.model.checkpoint
from projreg.model.net import MODEL_CONFIGS, build_model

HOSTILE = {
    "attn_splits": 10**6,  # predict asked for 1.5 PB
    "feature_channels": 65536,  # 17 GB
    "num_transformer_layers": 10**4,
    "ffn_dim_expansion": 10**4,
    "backbone_channels": [65536, 65536, 65536],
    "upsampler_channels": 10**6,
    "refine_radius": 10**4,
    "ssjm_lambda": float("nan"),
    "refine": "yes",
    "attention": "global",
}


@pytest.fixture(scope="module")
def weights():
    return build_model("small").state_dict()


@pytest.mark.parametrize("field", HOSTILE)
@pytest.mark.parametrize("command", ["predict", "export"])
def test_a_hostile_model_config_is_refused_before_building(probe, weights, tmp_path, monkeypatch, field, command):
    ckpt = tmp_path / "hostile.pt"
    torch.save({"model": weights, "model_config": {**MODEL_CONFIGS["small"], field: HOSTILE[field]}}, ckpt)
    built = []

    def record(**config):
        built.append(config)
        raise RuntimeError("a model was built")

    monkeypatch.setattr(projreg.model.checkpoint, "SSJMFlow", record)
    image = tmp_path / "a.png"
    assert cv2.imwrite(str(image), np.zeros((64, 64, 3), np.uint8))
    if command == "predict":
        args = ["predict", "--projected", image, "--captured", image, "--out", tmp_path / "f.exr", "--model", ckpt]
    else:
        args = ["export", "--checkpoint", ckpt, "--out", tmp_path / "slim.pt"]
    probe.error(probe.projreg(*args, *(["-q"] if command == "predict" else [])), ckpt, f"model_config {field}")
    assert built == []
    assert not (tmp_path / "f.exr").exists() and not (tmp_path / "slim.pt").exists()
