"""``projreg export --onnx``: one export of a tiny network (the exporter's symbolic tracing takes about
40 s of CPU even for it), then checks on the graph and onnxruntime against PyTorch."""

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from projreg.cli import app
from projreg.inference.runtime import OnnxNetwork, TorchNetwork, open_network
from projreg.model import checkpoint
from projreg.model.checkpoint import load_model, reference_checkpoint, reference_graph
from projreg.model.net import SSJMFlow
from projsynth.dataset.shards import ShardReader
from projsynth.flow.formats import read_flow_exr
from projsynth.utils.files import file_sha256

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

CPU = torch.device("cpu")
# every stage of the shipped `small`: SSJM, a shifted-window layer, the 1/4 refinement (grid_sample)
TINY = {
    "feature_channels": 8,
    "backbone_channels": [4, 4, 8],
    "num_transformer_layers": 2,
    "ffn_dim_expansion": 1,
    "attn_splits": 2,
    "refine": True,
    "refine_radius": 1,
    "upsampler_channels": 8,
}


def _cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """``(checkpoint, graph)``: a seeded tiny checkpoint and its export through the CLI."""
    root = tmp_path_factory.mktemp("onnx")
    torch.manual_seed(3)
    model = SSJMFlow(**TINY)
    ckpt, graph = root / "tiny.pt", root / "tiny.onnx"
    torch.save({"model": model.state_dict(), "model_config": model.config}, ckpt)
    result = _cli("export", "--checkpoint", ckpt, "--onnx", graph)
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert "opset 18" in result.stderr
    return ckpt, graph


@pytest.fixture(scope="module")
def pair(tiny_train):
    reader = ShardReader(tiny_train)
    try:
        s = reader.read(13)
    finally:
        reader.close()
    return s["projected"], s["captured"]


@pytest.mark.slow
def test_the_graph_is_checked_named_and_dynamic(exported):
    ckpt, graph = exported
    proto = onnx.load(str(graph))
    onnx.checker.check_model(proto, full_check=True)
    assert [i.name for i in proto.graph.input] == ["projected", "captured"]
    assert [o.name for o in proto.graph.output] == ["flow"]
    for value in (*proto.graph.input, *proto.graph.output):
        dims = value.type.tensor_type.shape.dim
        assert [d.dim_param or d.dim_value for d in dims][0::2] == ["batch", "height"] and dims[3].dim_param
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["projreg_checkpoint"] == "tiny.pt" and len(meta["projreg_checkpoint_sha256"]) == 64
    assert '"refine_radius": 1' in meta["projreg_model_config"]
    assert not list(graph.parent.glob("*.data"))  # weights inside the one file
    # onnxruntime's Softmax on any other axis transposes around itself: 20 ms of a 384 x 512 pair once
    softmax_axes = [a.i for n in proto.graph.node if n.op_type == "Softmax" for a in n.attribute if a.name == "axis"]
    assert softmax_axes and set(softmax_axes) == {-1}


@pytest.mark.slow
def test_two_exports_of_one_checkpoint_are_the_same_bytes(exported, tmp_path):
    ckpt, graph = exported
    again = tmp_path / "again.onnx"
    result = _cli("export", "--checkpoint", ckpt, "--onnx", again)
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert again.read_bytes() == graph.read_bytes()  # before: per-node stack traces named the tracer's counter


@pytest.mark.slow
def test_onnxruntime_matches_pytorch_at_two_sizes_and_in_batches(exported, pair):
    ckpt, graph = exported
    torch_net = TorchNetwork(SSJMFlow(**TINY), CPU)
    torch_net.model.load_state_dict(torch.load(ckpt, weights_only=True)["model"])
    ort_net = OnnxNetwork(graph, CPU, threads=1)
    img0, img1 = pair  # 64 x 96; then 90 x 130: neither the shard size nor a multiple of the padding
    big = [cv2.resize(i, (130, 90), interpolation=cv2.INTER_LINEAR) for i in pair]
    for a, b in ((img0[None], img1[None]), (big[0][None], big[1][None]), (np.stack([img0, img1]),) * 2):
        expected, got = torch_net(a, b), ort_net(a, b)
        assert got.shape == expected.shape == (*a.shape[:3], 2)
        assert np.median(np.abs(expected)) > 0.05  # a comparison of non-trivial flows
        diff = np.abs(got - expected)
        assert diff.mean() <= 0.01 and diff.max() <= 0.5, (a.shape, diff.mean(), diff.max())


@pytest.mark.slow
def test_predict_with_onnxruntime_writes_what_torch_writes(exported, pair, tmp_path):
    ckpt, graph = exported
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    for path, rgb in ((a, pair[0]), (b, pair[1])):
        assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    inputs = ["--projected", a, "--captured", b]
    flows = []
    for backend, model in (("torch", ckpt), ("onnxruntime", graph)):
        out = tmp_path / f"{backend}.exr"
        result = _cli("predict", *inputs, "--out", out, "--model", model, "--backend", backend, "--no-refine", "-q")
        assert result.exit_code == 0, (result.stderr, result.exception)
        flows.append(read_flow_exr(out)[0])
    assert np.abs(flows[0] - flows[1]).max() <= 0.01


def test_bad_export_options_are_one_line_errors(tiny_ckpt, tmp_path, one_line_error):
    one_line_error(
        _cli("export", "--checkpoint", tiny_ckpt, "--onnx", tmp_path / "m.onnx", "--opset", "15"), "--opset 15", "16"
    )
    one_line_error(_cli("export", "--checkpoint", tiny_ckpt, "--onnx", tmp_path / "m.onnx", "--opset", "99"), "..23")
    one_line_error(_cli("export", "--checkpoint", tiny_ckpt, "--onnx", tmp_path / "m.pt"), "--onnx", ".onnx")
    one_line_error(_cli("export", "--checkpoint", tiny_ckpt), "--out", "--onnx")
    one_line_error(
        _cli("export", "--checkpoint", tiny_ckpt, "--out", tmp_path / "a.pt", "--onnx", tmp_path / "m.onnx"),
        "one of them",
    )
    one_line_error(_cli("export", "--checkpoint", tmp_path / "none.pt", "--onnx", tmp_path / "m.onnx"), "none.pt")
    assert not list(tmp_path.iterdir())


def test_an_onnx_graph_runs_in_onnxruntime(tmp_path, one_line_error):
    a = tmp_path / "a.png"
    cv2.imwrite(str(a), np.zeros((32, 32, 3), np.uint8))
    fake = tmp_path / "m.onnx"
    fake.write_bytes(b"not a graph")
    args = ("predict", "--projected", a, "--captured", a, "--out", tmp_path / "f.exr", "--model", fake, "-q")
    one_line_error(_cli(*args, "--backend", "torch"), "--backend onnxruntime")
    one_line_error(_cli(*args), "m.onnx", "cannot load")  # auto: a graph runs in onnxruntime
    one_line_error(_cli(*args, "--backend", "onnxruntime"), "m.onnx", "cannot load")
    one_line_error(_cli(*args, "--backend", "onnxruntime", "--precision", "bf16"), "--precision bf16")


def test_the_shipped_graph_is_the_shipped_checkpoint(pair):
    """``make reference-onnx`` was run after the weights last changed: the graph records the checkpoint's
    SHA-256 and computes its flow (to float rounding) at the default network side and at the escalation's."""
    graph, ckpt = reference_graph(), reference_checkpoint()
    assert graph is not None and ckpt is not None
    net = OnnxNetwork(graph, CPU)
    assert net.metadata["projreg_checkpoint_sha256"] == file_sha256(ckpt), "stale graph: run `make reference-onnx`"
    torch_net = TorchNetwork(load_model(ckpt, CPU), CPU)
    for side in (256, 512):
        a, b = (cv2.resize(x, (side, side * 3 // 4), interpolation=cv2.INTER_AREA)[None] for x in pair)
        assert np.abs(net(a, b) - torch_net(a, b)).max() < 0.01


def test_auto_runs_the_reference_graph_where_onnxruntime_can(tiny_ckpt, monkeypatch, tmp_path):
    assert isinstance(open_network(None), OnnxNetwork) and isinstance(open_network("reference"), OnnxNetwork)
    assert isinstance(open_network(reference_checkpoint()), OnnxNetwork)
    copy = tmp_path / "weights.pt"  # the same weights elsewhere: the same graph
    copy.write_bytes(reference_checkpoint().read_bytes())
    assert isinstance(open_network(copy), OnnxNetwork)
    assert isinstance(open_network(None, backend="torch"), TorchNetwork)
    assert isinstance(open_network(None, precision="bf16"), TorchNetwork)  # the graph is float32
    assert isinstance(open_network(tiny_ckpt), TorchNetwork)  # a checkpoint of one's own: no graph of it
    # a graph exported from other weights than the shipped ones is not run in their place
    monkeypatch.setattr(checkpoint, "reference_checkpoint", lambda: Path(tiny_ckpt))
    stale = open_network(None)
    assert isinstance(stale, TorchNetwork) and stale.model.config == load_model(tiny_ckpt, CPU).config
    monkeypatch.undo()
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "onnxruntime" else find_spec(name, *a)
    )
    assert isinstance(open_network(None), TorchNetwork)  # without onnxruntime, torch
