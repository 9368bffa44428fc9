"""Inference options: device, precision, batches and the fast path (``projreg.inference.runtime``, ``predict``)."""

import cv2
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.cli import app
from projreg.evaluation.methods import ModelRun, model_methods
from projreg.inference.runtime import TorchNetwork, flows_resized, parse_device, parse_precision
from projreg.model.checkpoint import load_model
from projreg.refine.config import QUALITIES
from projreg.refine.refiner import GeometricRefiner
from projreg.training.validate import predict_flow
from projsynth.dataset.shards import ShardReader
from projsynth.flow.formats import read_flow_exr

CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def pairs(tiny_train):
    reader = ShardReader(tiny_train)
    try:
        return [(s["projected"], s["captured"]) for s in (reader.read(k) for k in (0, 5, 13))]
    finally:
        reader.close()


def test_devices_and_precisions_are_checked_here():
    assert parse_device("cpu") == CPU and parse_device(CPU) == CPU
    for bad in ("tpu", "cuda:x", "cpu:1"):
        with pytest.raises(ProjregError, match="--device .*expected cpu, cuda or cuda:N"):
            parse_device(bad)
    if not torch.cuda.is_available():
        with pytest.raises(ProjregError, match="--device cuda:1: CUDA is not available here"):
            parse_device("cuda:1")
    assert parse_precision("bf16", CPU) == torch.bfloat16
    with pytest.raises(ProjregError, match="--precision fp16: float16 runs on CUDA only"):
        parse_precision("fp16", CPU)
    with pytest.raises(ProjregError, match="--precision 'half'"):
        parse_precision("half", CPU)


def test_bf16_casts_the_feature_stages_and_keeps_flow_arithmetic_in_float32(tiny_ckpt, pairs):
    img0, img1 = pairs[0]
    fp32 = TorchNetwork(load_model(tiny_ckpt, CPU), CPU)(img0[None], img1[None])
    net = TorchNetwork(load_model(tiny_ckpt, CPU), CPU, torch.bfloat16)
    model = net.model
    assert model.feature_dtype == torch.bfloat16 and model.transformer.self_layers[0].q.weight.dtype == torch.bfloat16
    assert all(
        p.dtype == torch.float32 for m in (model.propagate8, model.propagate4, model.upsampler) for p in m.parameters()
    )
    bf16 = net(img0[None], img1[None])
    assert bf16.dtype == np.float32 and np.isfinite(bf16).all()
    # bfloat16 features move the matches a little, not the frame: well under a pixel on average
    assert np.abs(bf16 - fp32).mean() < 0.5, np.abs(bf16 - fp32).mean()


def test_batches_group_pairs_of_one_size_and_change_nothing(tiny_ckpt, pairs):
    net = TorchNetwork(load_model(tiny_ckpt, CPU), CPU)
    calls = []

    def counting(a, b):
        calls.append(a.shape)
        return net(a, b)

    big = tuple(cv2.resize(i, (120, 80), interpolation=cv2.INTER_LINEAR) for i in pairs[1])
    mixed = [pairs[0], big, pairs[2]]
    batched = flows_resized(counting, mixed, max_side=1024, batch_size=4)
    assert calls == [(2, 64, 96, 3), (1, 80, 120, 3)]  # the two 64 x 96 pairs in one call
    for (a, b), flow in zip(mixed, batched, strict=True):
        np.testing.assert_allclose(flow, predict_flow(net.model, a, b, CPU), atol=1e-4)


def test_predict_folder_mode_in_batches_writes_what_one_by_one_writes(tiny_ckpt, pairs, tmp_path):
    for k, (img0, img1) in enumerate(pairs):
        for side, rgb in (("P", img0), ("C", img1)):
            (tmp_path / side).mkdir(exist_ok=True)
            assert cv2.imwrite(str(tmp_path / side / f"{k}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    folders = ["--projected", str(tmp_path / "P"), "--captured", str(tmp_path / "C")]
    for batch in ("1", "2"):
        args = ["predict", *folders, "--out", str(tmp_path / batch), "--model", str(tiny_ckpt), "--no-refine"]
        result = CliRunner().invoke(app, [*args, "--batch-size", batch, "-q"])
        assert result.exit_code == 0, (result.stderr, result.exception)
    for k in range(len(pairs)):
        one, two = (read_flow_exr(tmp_path / b / f"{k}_flow.exr")[0] for b in ("1", "2"))
        np.testing.assert_allclose(two, one, atol=1e-4)


def test_the_fast_path_is_the_small_network_then_one_aligned_candidate(tiny_ckpt, pairs):
    img0, img1 = pairs[2]
    big0, big1 = (cv2.resize(i, (384, 256), interpolation=cv2.INTER_LINEAR) for i in (img0, img1))
    (method,) = model_methods(tiny_ckpt, "tiny", ModelRun(device=CPU, quality="fast"))
    assert method.name == "tiny-fast"
    pred = method.predict(big0, big1)
    net = TorchNetwork(load_model(tiny_ckpt, CPU), CPU)
    fast = QUALITIES["fast"]
    flow = flows_resized(net, [(big0, big1)], fast.network_side)[0]  # the network at 170 x 256
    expected, info = GeometricRefiner(fast.refine).predict_info(big0, big1, flow)
    np.testing.assert_allclose(pred.flow, expected.flow, atol=1e-4)
    refined = {key for key in info.scores if not key.endswith("-homography-aligned")}
    starts = {"network/normalised-aligned", "identity/normalised-aligned"}
    assert refined <= starts | {"grown/normalised-aligned"} and len(refined & starts) == 1  # one start (and grown)
    planes = {key.replace("-aligned", "-homography-aligned") for key in refined}
    assert set(info.scores) - refined <= planes  # and its homography alone
