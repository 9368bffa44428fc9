import hashlib
import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

import projreg.evaluation.bench
import projreg.evaluation.methods
import projreg.inference.pipeline
from projreg import ProjregError
from projreg.cli import app
from projreg.evaluation.baselines import parse_baselines
from projreg.evaluation.bench import GROUPS, run_bench
from projreg.evaluation.methods import Method
from projreg.evaluation.metrics import KEYS, EPEAccumulator, sample_indices
from projreg.evaluation.report import parse_threshold, to_markdown
from projreg.model.checkpoint import load_model
from projreg.prediction import Prediction, as_prediction
from projreg.refine.refiner import GeometricRefiner
from projreg.training.validate import predict_flow
from projsynth.dataset.shards import ShardReader

CPU = torch.device("cpu")
ROLES = {"natural_on_generated", "generated_on_natural"}
FAMILIES = {"planar", "lens", "cylinder_convex", "cylinder_concave", "sphere_convex", "sphere_concave", "wave", "bumps"}
SHIFT = np.array([1.2, 1.6], np.float32)  # |SHIFT| = 2 px


def _samples(root, indices=None):
    reader = ShardReader(root)
    try:
        return [reader.read(k) for k in (indices if indices is not None else range(len(reader)))]
    finally:
        reader.close()


def _key(img0, img1):
    return hashlib.sha256(img0.tobytes() + img1.tobytes()).hexdigest()


@pytest.fixture(scope="module")
def oracles(tiny_train):
    """A zero-flow predictor and a ground truth shifted by SHIFT (EPE exactly 2 px everywhere)."""
    gt = {_key(s["projected"], s["captured"]): s["flow"] for s in _samples(tiny_train)}
    zero = Method("zero", "baseline", lambda a, b: np.zeros((*a.shape[:2], 2), np.float32))
    shifted = Method("shifted", "baseline", lambda a, b: gt[_key(a, b)] + SHIFT)
    return [zero, shifted]


@pytest.fixture(scope="module")
def report(tiny_train, tiny_ckpt, oracles):
    return run_bench(tiny_train, models=[tiny_ckpt], baselines=["dis-medium"], extra_methods=oracles, device=CPU)


def _by_name(report):
    return {r["name"]: r for r in report["results"]}


def _cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_report_schema(report, tiny_train):
    assert set(report) == {"dataset", "reference_model", "results", "versus_baselines"}
    manifest = json.loads((tiny_train / "manifest.json").read_text())
    assert report["dataset"] == {
        "path": str(tiny_train),
        "num_samples": 16,
        "evaluated": 16,
        "size": [64, 96],
        "camera_size": [64, 96],
        "seed": 0,
        "split": "train",
        "config_hash": manifest["config_hash"],
    }
    assert report["reference_model"] is None
    assert [(r["name"], r["kind"]) for r in report["results"]] == [
        ("last", "model"),
        ("dis-medium", "baseline"),
        ("zero", "baseline"),
        ("shifted", "baseline"),
    ]
    for r in report["results"]:
        extra = {"reliability"} if r["refined"] and any(p["registered"] for p in r["pairs"]) else set()
        assert set(r) == {"name", "kind", "refined", *KEYS, "ms_per_pair", "groups", "pairs", "unregistered", *extra}
        assert [p["id"] for p in r["pairs"]] == [s["params"]["sample_id"] for s in _samples(tiny_train)]
        assert r["ms_per_pair"] > 0
        assert tuple(r["groups"]) == GROUPS
        assert set(r["groups"]["role"]) == ROLES
        assert set(r["groups"]["family"]) == FAMILIES
        assert set(r["groups"]["condition"]) == {"studio", "night", "daylight", "translucent", "noisy"}
        assert list(r["groups"]["pair_role"]) == ["pair 0 / natural_on_generated", "pair 0 / generated_on_natural"]
        for group in r["groups"].values():
            for res in group.values():
                assert set(res) == set(KEYS)
    json.dumps(report, allow_nan=False)


@pytest.mark.parametrize("name", ["last", "dis-medium"])
def test_pooled_metrics_equal_direct_recomputation(report, tiny_train, tiny_ckpt, name):
    if name == "last":
        model, refiner = load_model(tiny_ckpt, CPU), GeometricRefiner()
        predict = lambda a, b: refiner.predict(a, b, predict_flow(model, a, b, CPU))  # noqa: E731
    else:
        predict = projreg.evaluation.methods.baseline_method("dis-medium").predict
    acc = EPEAccumulator()
    for s in _samples(tiny_train):
        pred = as_prediction(predict(s["projected"], s["captured"]))
        acc.add(pred.flow, s["flow"], s["valid"], pred.claimed, s["params"]["sample_id"])
    direct, got = acc.result(), _by_name(report)[name]
    for key in KEYS:
        if direct[key] is None or isinstance(direct[key], str):  # no flow above 10 px; worst_id
            assert got[key] == direct[key], key
        else:
            assert got[key] == pytest.approx(direct[key], rel=1e-9, abs=1e-12), key


def test_groups_partition_the_pixels(report):
    for r in report["results"]:
        for kind in GROUPS:
            groups = r["groups"][kind].values()
            assert sum(g["pixels"] for g in groups) == r["pixels"], (r["name"], kind)
            assert sum(g["images"] for g in groups) == r["images"] == 16
            pooled = sum(g["epe"] * g["pixels"] for g in groups) / r["pixels"]
            assert pooled == pytest.approx(r["epe"], rel=1e-9)


def test_zero_predictor_and_shifted_oracle_give_hand_computed_metrics(report, tiny_train):
    samples = _samples(tiny_train)
    mags = [np.hypot(*s["flow"][s["valid"]].astype(np.float64).T) for s in samples]
    mag = np.concatenate(mags)
    res = _by_name(report)
    zero = res["zero"]
    assert zero["pixels"] == sum(int(s["valid"].sum()) for s in samples) == mag.size
    assert zero["epe"] == pytest.approx(mag.mean(), rel=1e-9)
    assert zero["s0-10"] == pytest.approx(mag[mag < 10].mean(), rel=1e-9)
    assert zero["s40+"] is None and not (mag > 40).any()
    assert zero["px1"] == pytest.approx((mag > 1).mean(), rel=1e-9)
    role0 = np.concatenate(
        [m for m, s in zip(mags, samples, strict=True) if s["params"]["role"] == "natural_on_generated"]
    )
    assert zero["groups"]["role"]["natural_on_generated"]["epe"] == pytest.approx(role0.mean(), rel=1e-9)

    shifted = res["shifted"]
    assert shifted["epe"] == pytest.approx(2.0, abs=1e-4) and shifted["image_epe"] == pytest.approx(2.0, abs=1e-4)
    assert (shifted["px1"], shifted["px3"], shifted["px5"]) == (1.0, 0.0, 0.0)
    for group in shifted["groups"].values():
        for g in group.values():
            assert g["epe"] == pytest.approx(2.0, abs=1e-4)
    # a real method must beat predicting no motion
    assert res["dis-medium"]["epe"] < 0.7 * zero["epe"]


def test_per_pair_distribution_worst_pair_and_claims_are_hand_computed(tiny_train, monkeypatch):
    """The worst cases beside the pooled figures, on a method that claims half of each frame."""
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)
    samples = _samples(tiny_train)
    gt = {_key(s["projected"], s["captured"]): s for s in samples}

    def half(a, b):  # zero flow, claiming the left half of the frame; the 4th sample unregistered
        s = gt[_key(a, b)]
        claimed = np.zeros(s["valid"].shape, bool)
        claimed[:, : claimed.shape[1] // 2] = True
        if s is samples[3]:
            return Prediction(np.zeros_like(s["flow"]), np.zeros_like(claimed), False, "textureless")
        return Prediction(np.zeros_like(s["flow"]), claimed)

    shifted = Method("shifted", "baseline", lambda a, b: gt[_key(a, b)]["flow"] + SHIFT)
    rep = run_bench(tiny_train, baselines=[], extra_methods=[Method("half", "model", half), shifted], device=CPU)
    (r, b), v = rep["results"], rep["versus_baselines"]
    mags = [np.hypot(*s["flow"].astype(np.float64).transpose(2, 0, 1)) for s in samples]  # zero flow: EPE = |gt|
    per_pair = np.array([m[s["valid"]].mean() for m, s in zip(mags, samples, strict=True)])
    ids = [s["params"]["sample_id"] for s in samples]
    w = samples[0]["valid"].shape[1] // 2
    left = [s["valid"].copy() for s in samples]
    for k, m in enumerate(left):
        m[:, w:] = False
        if k == 3:
            m[:] = False
    assert r["pair_median"] == pytest.approx(np.median(per_pair), rel=1e-9)
    assert r["pair_p90"] == pytest.approx(np.percentile(per_pair, 90), rel=1e-9)
    assert r["worst_epe"] == pytest.approx(per_pair.max(), rel=1e-9) and r["worst_id"] == ids[int(per_pair.argmax())]
    claimed_px = sum(int(m.sum()) for m in left)
    assert r["claimed"] == pytest.approx(claimed_px / r["pixels"], rel=1e-9)
    shares = [m.sum() / s["valid"].sum() for m, s in zip(left, samples, strict=True)]
    assert r["claimed_mean"] == pytest.approx(np.mean(shares), rel=1e-9)
    epe_claimed = sum(float(mag[m].sum()) for mag, m in zip(mags, left, strict=True)) / claimed_px
    assert r["epe_claimed"] == pytest.approx(epe_claimed, rel=1e-9)
    assert r["unregistered"] == [ids[3]] and [p["registered"] for p in r["pairs"]].count(False) == 1
    assert r["pairs"][3]["epe_claimed"] is None and r["pairs"][0]["epe"] == pytest.approx(per_pair[0], rel=1e-9)
    # the baseline is 2 px off everywhere: per pair, the ratio is the claimed EPE over 2
    ratios = [mag[m].mean() / 2 for k, (mag, m) in enumerate(zip(mags, left, strict=True)) if k != 3]
    assert b["pair_median"] == pytest.approx(2.0, abs=1e-4) and b["claimed"] == 1.0
    vs = v["half"]
    assert (vs["pairs"], vs["rated"], vs["baselines"], vs["best_baseline"]) == (16, 15, ["shifted"], "shifted")
    assert vs["worst_ratio"] == pytest.approx(max(ratios), rel=1e-4)
    assert vs["within"] == pytest.approx(np.mean(np.array(ratios) <= 1.5))
    assert vs["claimed_mean"] == pytest.approx(np.mean(shares), rel=1e-9)
    assert vs["mean_pair_epe"] == pytest.approx(per_pair.mean(), rel=1e-9)
    assert vs["best_baseline_mean_pair_epe"] == pytest.approx(2.0, abs=1e-4)
    md = to_markdown(rep)
    assert (
        f"| half | {r['epe']:.2f} | {r['pair_median']:.2f} | {r['pair_p90']:.2f} | {r['worst_epe']:.2f} | "
        f"{r['worst_id']} | {100 * r['claimed']:.2f} | {r['epe_claimed']:.2f} | 1 |" in md
    )
    assert f"| half | 15 / 16 | {100 * vs['within']:.2f} | {vs['worst_ratio']:.2f} |" in md


def test_limit_spreads_samples_and_no_reference_runs_baselines_only(tiny_train, tmp_path, monkeypatch):
    assert sample_indices(16, 4) == [0, 5, 10, 15]
    assert sample_indices(3, 10) == [0, 1, 2]
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)
    out = tmp_path / "b.json"
    result = _cli("bench", "--data", tiny_train, "--baselines", "dis-fast", "--limit", "4", "--json", out, "-q")
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert "no shipped reference model" in result.stderr
    rep = json.loads(out.read_text())
    assert rep["reference_model"] is None and rep["dataset"]["evaluated"] == 4
    (r,) = rep["results"]
    assert r["name"] == "dis-fast" and r["images"] == 4
    acc = EPEAccumulator()
    predict = projreg.evaluation.methods.baseline_method("dis-fast").predict
    for s in _samples(tiny_train, [0, 5, 10, 15]):
        acc.add(as_prediction(predict(s["projected"], s["captured"])).flow, s["flow"], s["valid"])
    assert r["epe"] == pytest.approx(acc.result()["epe"], rel=1e-9)


def test_shipped_reference_is_benchmarked_without_model(tiny_train, tiny_ckpt, monkeypatch):
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: tiny_ckpt)
    rep = run_bench(tiny_train, baselines=[], limit=2, device=CPU)
    assert rep["reference_model"] == str(tiny_ckpt)
    assert [(r["name"], r["kind"]) for r in rep["results"]] == [("reference", "model")]


def test_fail_above_gates_models_only(tiny_train, tiny_ckpt, tmp_path, one_line_error):
    out = tmp_path / "b.json"
    base = ["bench", "--data", tiny_train, "--model", tiny_ckpt, "--baselines", "dis-fast", "--limit", "2", "-q"]
    result = _cli(*base, "--json", out, "--fail-above", "epe=0.0001", "--fail-above", "px5=1")
    assert result.exit_code == 1, (result.stderr, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "last" in lines[0] and "epe" in lines[0] and "0.0001" in lines[0], lines
    epe = json.loads(out.read_text())["results"][0]["epe"]  # written before gating
    assert f"{epe:.4f}" in lines[0]
    assert _cli(*base, "--fail-above", "epe=1e9").exit_code == 0
    one_line_error(_cli(*base, "--fail-above", "nonsense"), "--fail-above", "nonsense")
    one_line_error(_cli(*base, "--fail-above", "px9=1"), "--fail-above")
    with pytest.raises(Exception, match="--fail-above"):
        parse_threshold("epe=nan")


def test_refine_modes_name_the_rows_and_the_raw_row_is_the_network_alone(tiny_train, tiny_ckpt):
    both = run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=2, refine="both", device=CPU)
    off = run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=2, refine="off", device=CPU)
    on = run_bench(tiny_train, models=[tiny_ckpt], baselines=["dis-fast"], limit=2, device=CPU)
    assert [(r["name"], r["refined"]) for r in both["results"]] == [("last", True), ("last-raw", False)]
    assert [(r["name"], r["refined"]) for r in off["results"]] == [("last", False)]
    assert [(r["name"], r["refined"]) for r in on["results"]] == [("last", True), ("dis-fast", False)]
    assert both["results"][1]["epe"] == off["results"][0]["epe"]
    assert both["results"][0]["epe"] == on["results"][0]["epe"] != off["results"][0]["epe"]
    with pytest.raises(ProjregError, match="--refine"):
        run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=2, refine="maybe", device=CPU)
    with pytest.raises(ProjregError, match="--refine"):  # checked even when no model would use it
        run_bench(tiny_train, models=[], baselines=["dis-fast"], limit=2, refine="Both", device=CPU)


def test_named_thresholds_gate_one_model(tiny_train, tiny_ckpt, tmp_path, one_line_error):
    assert parse_threshold("last-raw:px3=0.5") == ("px3", 0.5, "last-raw")
    base = ["bench", "--data", tiny_train, "--model", tiny_ckpt, *"--baselines none --limit 2 --refine both -q".split()]
    result = _cli(*base, "--fail-above", "last-raw:epe=0.0001", "--fail-above", "last:epe=1e9")
    assert result.exit_code == 1, (result.stderr, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("projreg: fail-above: last-raw: epe"), lines
    one_line_error(_cli(*base, "--fail-above", "nobody:epe=1"), "nobody", "last-raw")
    one_line_error(_cli(*base, "--fail-above", ":epe=1"), "--fail-above")


def test_markdown_has_table2_rows_and_compact_table(tiny_train, tiny_ckpt, tmp_path):
    md, js = tmp_path / "b.md", tmp_path / "b.json"
    args = ["bench", "--data", tiny_train, "--model", tiny_ckpt, "--baselines", "dis-fast,farneback", "--limit", "3"]
    result = _cli(*args, "--markdown", md, "--json", js, "-q")
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert result.stdout == ""
    lines = md.read_text().splitlines()
    header = "| method | metric | pair 0 / natural_on_generated | pair 0 / generated_on_natural | all |"
    assert lines.count(header) == 1
    results = json.loads(js.read_text())["results"]
    for r in results:
        for label, key in (("EPE", "epe"), ("s0-10", "s0-10"), ("s10-40", "s10-40"), ("s40+", "s40+")):
            (row,) = [line for line in lines if line.startswith(f"| {r['name']} | {label} |")]
            cells = [c.strip() for c in row.strip("|").split("|")]
            assert len(cells) == 5
            assert cells[-1] == ("–" if r[key] is None else f"{r[key]:.2f}")
    compact = [line for line in lines if line.startswith("| method | kind | EPE |")]
    assert len(compact) == 1
    stdout = _cli(*args, "-q").stdout.splitlines()
    assert stdout[0] == compact[0] and len(stdout) == 2 + len(results)
    assert [line.split("|")[1].strip() for line in stdout[2:]] == ["last", "dis-fast", "farneback"]


def test_errors_name_the_path(tiny_train, tmp_path, one_line_error):
    missing = tmp_path / "nope"
    one_line_error(_cli("bench", "--data", missing, "-q"), missing)
    bad_ckpt = tmp_path / "bad.pt"
    bad_ckpt.write_bytes(b"not a checkpoint")
    one_line_error(_cli("bench", "--data", tiny_train, "--model", bad_ckpt, "-q"), bad_ckpt)
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    for f in tiny_train.iterdir():
        (corrupt / f.name).write_bytes(f.read_bytes())
    (corrupt / "shard-00001.h5").write_bytes(b"garbage" * 100)
    one_line_error(_cli("bench", "--data", corrupt, "--baselines", "dis-fast", "-q"), corrupt / "shard-00001.h5")
    one_line_error(_cli("bench", "--data", tiny_train, "--baselines", "nope", "-q"), "nope")
    one_line_error(_cli("bench", "--data", tiny_train, "--limit", "0", "-q"), "--limit")
    one_line_error(_cli("bench", "--data", tiny_train, "--model", bad_ckpt, "--model", bad_ckpt, "-q"), "twice")
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"a file where a folder is needed")
    report = tmp_path / "out" / "r.json"
    options = "--baselines dis-fast --limit 1 --model reference".split()
    result = _cli("bench", "--data", tiny_train, *options, "--json", report, "--markdown", blocker / "r.md", "-q")
    one_line_error(result, blocker / "r.md")
    assert not report.exists()  # both outputs or neither


def test_track_rows_carry_every_metric_the_jitter_and_how_frames_were_registered(tiny_sequences, tiny_ckpt):
    report = run_bench(
        tiny_sequences, models=[tiny_ckpt], baselines=["dis-fast", "sift-ransac"], device=CPU, track=True
    )
    rows = _by_name(report)
    assert list(rows) == ["last", "last+track", "dis-fast", "sift-ransac", "dis-fast+track"]  # no sift tracking
    for name in ("last+track", "dis-fast+track"):
        assert set(rows["last"]) - {"jitter", "reliability"} <= set(rows[name]) and rows[name]["ms_mean"] > 0
        assert sum(rows[name]["tracking"].values()) == 12 and rows[name]["tracking"]["full"] == 4
        assert rows[name]["kind"] == rows[name.split("+")[0]]["kind"]
    assert all(r["jitter"] is not None and r["jitter"] >= 0 for r in rows.values())
    # the jitter of a row is JitterAccumulator's over its own flows, sequence by sequence
    from projreg.evaluation.baselines import make_baseline
    from projreg.inference.track import JitterAccumulator

    dis, acc = make_baseline("dis-fast"), JitterAccumulator()
    samples = _samples(tiny_sequences)
    for s in samples:
        acc.add(s["params"]["sequence"], dis.predict(s["projected"], s["captured"]), s["flow"], s["valid"])
    assert rows["dis-fast"]["jitter"] == pytest.approx(acc.result(), rel=1e-9)
    # each sequence's first frame is the full method's own answer
    for i, s in enumerate(samples):
        if s["params"]["frame"] == 0:
            assert rows["dis-fast+track"]["pairs"][i]["epe"] == pytest.approx(rows["dis-fast"]["pairs"][i]["epe"])
            assert rows["last+track"]["pairs"][i]["epe"] == pytest.approx(rows["last"]["pairs"][i]["epe"], rel=1e-5)
    # --limit counts whole sequences
    one = run_bench(tiny_sequences, baselines=["dis-fast"], models=[tiny_ckpt], device=CPU, track=True, limit=1)
    assert [p["id"] for p in one["results"][0]["pairs"]] == [s["params"]["sample_id"] for s in samples[:3]]


def test_track_needs_sequences_and_the_refinement(tiny_train, tiny_sequences, tiny_ckpt):
    with pytest.raises(ProjregError, match="--track: .* single frames"):
        run_bench(tiny_train, baselines=["dis-fast"], track=True)
    with pytest.raises(ProjregError, match="--track .*--refine on or both"):
        run_bench(tiny_sequences, models=[tiny_ckpt], baselines=[], refine="off", device=CPU, track=True)


def test_track_cli_with_compensation_scores_every_frame(tiny_sequences, tmp_path, monkeypatch):
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)
    out = tmp_path / "t.json"
    options = "--baselines dis-fast --track --compensation --limit 1".split()
    result = _cli("bench", "--data", tiny_sequences, *options, "--json", out, "-q")
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert "| jitter |" in result.stdout.splitlines()[0]
    rows = _by_name(json.loads(out.read_text()))
    assert list(rows) == ["dis-fast", "dis-fast+track", "uncompensated"]
    for name in ("dis-fast", "dis-fast+track"):
        assert rows[name]["images"] == 3 and 10 < rows[name]["comp_psnr"] < 99
    assert rows["uncompensated"]["comp_psnr"] < rows["dis-fast"]["comp_psnr"]


def test_refine_only_is_a_baseline_row_beside_sift(tiny_train, monkeypatch):
    """`--baselines sift-ransac,refine-only`: the refinement without the network is a baseline row
    (never gated), with the pixels it claims; its SIFT start is the sift-ransac row's homography."""
    monkeypatch.setattr(projreg.evaluation.methods, "reference_checkpoint", lambda: None)
    rep = run_bench(tiny_train, baselines=parse_baselines("sift-ransac,refine-only"), device=CPU)
    rows = {r["name"]: r for r in rep["results"]}
    assert list(rows) == ["sift-ransac", "refine-only"]
    only = rows["refine-only"]
    assert only["kind"] == "baseline" and not only["refined"] and math.isfinite(only["epe"])
    assert 0.0 <= only["claimed"] <= 1.0 and len(only["pairs"]) == len(rows["sift-ransac"]["pairs"])


def test_batches_of_samples_change_no_flow(tiny_train, tiny_ckpt, monkeypatch):
    """``--batch-size``: the network runs on several samples per call; every figure stays the same."""
    calls = []
    flows_resized = projreg.inference.pipeline.flows_resized

    def counting(net, pairs, max_side, batch_size=1):
        calls.append((len(pairs), batch_size))
        return flows_resized(net, pairs, max_side, batch_size)

    monkeypatch.setattr(projreg.inference.pipeline, "flows_resized", counting)
    one = run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=5, refine="both", device=CPU)
    calls.clear()
    three = run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=5, refine="both", device=CPU, batch_size=3)
    assert calls == [(1, 1), (1, 1), (3, 3), (2, 3)]  # each row's warm-up, then 3 + 2 samples for both rows
    for a, b in zip(one["results"], three["results"], strict=True):
        assert a["name"] == b["name"]
        np.testing.assert_allclose([p["epe"] for p in b["pairs"]], [p["epe"] for p in a["pairs"]], atol=1e-4)
        assert b["ms_per_pair"] > 0
    for bad, match in (({"batch_size": 0}, "--batch-size must be >= 1"), ({"batch_size": 2, "track": True}, "--track")):
        with pytest.raises(ProjregError, match=match):
            run_bench(tiny_train, models=[tiny_ckpt], baselines=[], limit=2, device=CPU, **bad)


def test_bench_takes_a_batch_size(tiny_train, tiny_ckpt, tmp_path):
    out = tmp_path / "b.json"
    args = ["--data", tiny_train, "--model", tiny_ckpt, "--baselines", "none", "--limit", "3", "--json", out]
    result = _cli("bench", *args, "--batch-size", "2", "-q")
    assert result.exit_code == 0, result.stderr
    assert json.loads(out.read_text())["results"][0]["images"] == 3


def test_the_default_model_row_escalates_to_the_network_at_its_full_side(monkeypatch, tiny_val):
    """``bench``'s default row is what ``predict`` runs: the network at 256 px, and on a pair the first
    stage leaves unverified (here: the camera saw black) the network again at 512 px at most."""
    from projreg.model.checkpoint import reference_checkpoint
    from projreg.refine.config import DEFAULT_QUALITY, QUALITIES

    asked = []
    real = projreg.inference.pipeline.finer_flow

    def spy(net, projected, captured, side):
        inner = real(net, projected, captured, side)
        return None if inner is None else (lambda: asked.append(side) or inner())

    monkeypatch.setattr(projreg.inference.pipeline, "finer_flow", spy)
    method = projreg.evaluation.methods.model_methods(reference_checkpoint())[0]
    assert method.name == "reference"
    reader = ShardReader(tiny_val)
    try:
        s = reader.read(0)
    finally:
        reader.close()
    pred = as_prediction(method.predict(s["projected"], np.zeros_like(s["captured"])))
    assert asked == [QUALITIES[DEFAULT_QUALITY].escalate_side] == [512] and not pred.registered
