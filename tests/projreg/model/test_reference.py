"""The shipped reference model: it ships, loads by name, and passes the CI gate of reference_gate.json.

The gate benchmarks the reference on a small test split that no training run used (its own seed)
and fails when any gated metric exceeds the recorded threshold, so a change that makes the model,
its inference or the generator worse fails ``make test``. The thresholds are the figures measured
when the model was shipped plus a margin (docs/history/2026-11-log.md); tighten them when a better model ships.
"""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from projreg.api import Registrar
from projreg.cli import app
from projreg.evaluation.report import check_thresholds, parse_threshold
from projreg.model.checkpoint import load_checkpoint, reference_checkpoint
from projreg.model.net import MODEL_CONFIGS
from projreg.refine.config import DEFAULT_QUALITY
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import resolve_plan
from projsynth.dataset.shards import ShardReader
from projsynth.flow.formats import read_flow_exr

GATE = json.loads(Path(__file__).with_name("reference_gate.json").read_text())


@pytest.fixture(scope="module")
def gate_data(tmp_path_factory):
    spec = GATE["data"]
    plan = resolve_plan(
        size=tuple(spec["size"]),
        seed=spec["seed"],
        split=spec["split"],
        pairs=spec["pairs"],
        transforms=spec["transforms"],
        blend="paper",
    )
    root = tmp_path_factory.mktemp("gate") / "test"
    generate(plan, root, shard_size=16)
    return root


@pytest.fixture(scope="module")
def gate_report(gate_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("gate") / "bench.json"
    args = [
        "bench",
        "--data",
        str(gate_data),
        "--baselines",
        ",".join(GATE["baselines"]),
        "--refine",
        "both",
        "--backend",  # the thresholds' runtime (docs/design.md, "CI gate")
        "torch",
        "--json",
        str(out),
        "-q",
    ]
    for metric, limit in GATE["fail_above"].items():
        args += ["--fail-above", f"{metric}={limit}"]
    result = CliRunner().invoke(app, args)
    return result, json.loads(out.read_text()) if out.exists() else None


def test_reference_ships_under_16_mib_as_a_small_model():
    ref = reference_checkpoint()
    assert ref is not None, "projreg/weights/reference.pt is missing: `make reference-model` rebuilds it"
    assert ref.stat().st_size < 16 * 2**20
    ckpt = load_checkpoint(ref)
    assert set(ckpt) >= {"model", "model_config", "train_config", "step"} and "optimizer" not in ckpt
    config = {k: v for k, v in ckpt["model_config"].items() if k not in ("use_ssjm", "ssjm_lambda")}
    assert config == MODEL_CONFIGS["small"] and ckpt["model_config"]["use_ssjm"] is True


def test_ci_gate_passes_and_the_reference_is_the_default_model(gate_report):
    result, report = gate_report
    assert result.exit_code == 0, result.stderr
    ref, raw = report["results"][:2]
    assert ref["name"] == "reference" and ref["kind"] == "model" and ref["refined"] and report["reference_model"]
    assert raw["name"] == "reference-raw" and raw["kind"] == "model" and not raw["refined"]
    assert ref["epe"] < raw["epe"] / 2  # the refinement is doing its job
    assert report["dataset"]["evaluated"] == 2 * len(GATE["data"]["transforms"].split(","))


def test_the_gate_can_fail(gate_report):
    _, report = gate_report
    two = {k: v for k, v in GATE["two_verdicts"].items() if k != "about"}
    for key, limit in GATE["fail_above"].items():  # no recorded threshold is vacuous
        if key not in two:
            assert check_thresholds(report, [parse_threshold(f"{key}={limit / 2}")]), key
    for key, (_, high) in two.items():  # at most its higher recorded value, the threshold near that
        name, metric = key.split(":")
        value = next(r[metric] for r in report["results"] if r["name"] == name)
        assert value <= 1.1 * high, (key, value)
        assert high < GATE["fail_above"][key] <= 1.5 * high, key


def test_predict_uses_the_reference_by_default(gate_data, tmp_path):
    reader = ShardReader(gate_data)
    try:
        s = reader.read(3)
    finally:
        reader.close()
    for name, img in (("p.png", s["projected"]), ("c.png", s["captured"])):
        assert cv2.imwrite(str(tmp_path / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    args = ["predict", "--projected", tmp_path / "p.png", "--captured", tmp_path / "c.png", "--out", tmp_path / "f.exr"]
    result = CliRunner().invoke(app, [str(a) for a in args] + ["-q"])
    assert result.exit_code == 0, result.stderr
    flow = read_flow_exr(tmp_path / "f.exr")[0]
    named = Registrar(reference_checkpoint(), quality=DEFAULT_QUALITY, device="cpu")  # the weights named
    np.testing.assert_allclose(flow, named.register(s["projected"], s["captured"]).flow, atol=1e-4)
    epe = np.linalg.norm(flow - s["flow"], axis=-1)[s["valid"]].mean()
    assert epe < np.linalg.norm(s["flow"], axis=-1)[s["valid"]].mean(), epe  # better than predicting zero flow
