"""Compensation judged by the camera's view: re-rendering is exact, the scores rank flows by what shows."""

import numpy as np
import pytest

from projreg import ProjregError
from projreg.evaluation.bench import run_bench
from projreg.evaluation.closedloop import UNCOMPENSATED, ClosedLoop
from projreg.evaluation.methods import Method
from projreg.evaluation.report import to_markdown
from projreg.prediction import Prediction
from projsynth.dataset.rerender import Rerenderer
from projsynth.dataset.shards import ShardReader


def test_rerendering_the_projected_image_gives_the_stored_photo_back(tiny_train, tiny_physical):
    for root in (tiny_train, tiny_physical):
        reader, rerenderer = ShardReader(root), Rerenderer(root)
        for k in range(0, len(reader), 3):
            s = reader.read(k)
            view = rerenderer.views(k, [s["projected"]])[0]
            np.testing.assert_array_equal(view.image, s["captured"])


def test_photos_without_noise_keep_the_scene_and_drop_the_sensor_noise(tiny_train, tiny_physical):
    for root in (tiny_train, tiny_physical):
        reader, rerenderer = ShardReader(root), Rerenderer(root)
        s = reader.read(1)
        clean, again = (rerenderer.views(1, [s["projected"]], noise=False)[0].image for _ in range(2))
        np.testing.assert_array_equal(clean, again)  # no random stream left
        residual = s["captured"].astype(np.float64) - clean  # the stored photo's noise: present, zero-mean-ish, small
        assert 0 < np.std(residual) < 8 and abs(np.mean(residual)) < 2


def test_scores_rank_flows_by_their_error(tiny_physical):
    reader, loop = ShardReader(tiny_physical), ClosedLoop(tiny_physical)
    for k in range(len(reader)):
        s = reader.read(k)
        flows = {"truth": s["flow"], **{f"off{d}": s["flow"] + np.float32(d) for d in (1, 3)}}
        scores = loop.score(k, s, flows)
        assert scores["truth"]["comp_psnr"] == 99.0 and scores["truth"]["comp_ssim"] == pytest.approx(1.0, abs=1e-3)
        psnr = [scores[n]["comp_psnr"] for n in ("truth", "off1", "off3")]
        assert psnr == sorted(psnr, reverse=True), psnr
        assert scores[UNCOMPENSATED]["comp_psnr"] < 60
        assert scores["off3"]["comp_ssim"] < scores["off1"]["comp_ssim"] < 1


def test_bench_reports_compensation_rows(tiny_train):
    zero = Method("zero", "baseline", lambda a, b: np.zeros((*a.shape[:2], 2), np.float32))
    report = run_bench(tiny_train, baselines=("dis-medium",), extra_methods=[zero], limit=4, compensation=True)
    rows = {r["name"]: r for r in report["results"]}
    assert list(rows)[-1] == UNCOMPENSATED and rows[UNCOMPENSATED]["kind"] == "none"
    assert rows[UNCOMPENSATED]["epe"] is None
    for name in ("reference", "dis-medium", "zero", UNCOMPENSATED):
        assert 0 < rows[name]["comp_psnr"] < 99 and 0 < rows[name]["comp_ssim"] <= 1
    assert rows["reference"]["comp_psnr"] > rows[UNCOMPENSATED]["comp_psnr"]
    assert "comp PSNR dB" in to_markdown(report)


def test_compensation_needs_a_generated_dataset(tmp_path, tiny_train):
    (tmp_path / "dataset.json").write_text('{"captured": {}}')
    with pytest.raises(ProjregError, match="--compensation"):
        ClosedLoop(tmp_path)


def test_bench_writes_a_labelled_contact_sheet(tiny_train, tmp_path):
    import cv2
    from typer.testing import CliRunner

    from projreg.cli import app

    sheet = tmp_path / "sheet.png"
    args = [
        "bench",
        "--data",
        str(tiny_train),
        "--baselines",
        "none",
        "--limit",
        "2",
        "--compensation",
        "--photometric",
        "--sheet",
        str(sheet),
        "--quiet",
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.stderr
    picture = cv2.imread(str(sheet))
    assert picture.shape[1] == 5 * 96 and picture.shape[0] == 22 + 2 * 64  # header + two samples
    bad = CliRunner().invoke(app, ["bench", "--data", str(tiny_train), "--sheet", str(sheet)])
    assert bad.exit_code == 2 and "--compensation" in bad.stderr


def test_the_default_compensation_ignores_the_claim_and_the_claimed_only_one_is_scored_beside_it(tiny_physical):
    reader, loop = ShardReader(tiny_physical), ClosedLoop(tiny_physical)
    s = reader.read(0)
    half = np.zeros(s["valid"].shape, bool)
    half[:, : half.shape[1] // 2] = True
    answers = {
        "whole": Prediction(s["flow"], np.ones_like(half)),
        "half": Prediction(s["flow"], half),  # the same flow, half of it claimed
        "unregistered": Prediction(s["flow"] + np.float32(9), np.zeros_like(half), registered=False),
    }
    scores = loop.score(0, s, answers)
    assert scores["half"]["comp_psnr"] == scores["whole"]["comp_psnr"] == 99.0  # the claim does not mask
    assert scores["whole"]["comp_psnr_claimed"] == 99.0 and scores["half"]["comp_psnr_claimed"] < 40
    # a pair reported as not registered is projected as it is, whatever its flow
    assert scores["unregistered"]["comp_psnr"] == scores[UNCOMPENSATED]["comp_psnr"]
    assert scores["half"]["comp_shown"] == scores["whole"]["comp_shown"] == 1.0  # the truth lands in the frame
    assert scores["unregistered"]["comp_shown"] == 1.0


def test_the_measured_response_calibrates_the_photometric_loop(small_physical, tiny_train):
    """Per sample the camera's views of the grey levels are fitted; on the physical model (projector gamma
    2.2, camera 2.0-2.4) the measured curves score as the assumed gamma does, within 0.3 dB, and the
    report says where its curves came from."""
    kwargs = {"baselines": ("dis-medium",), "compensation": True, "photometric": True}
    measured = run_bench(small_physical, response="measured", **kwargs)
    assumed = run_bench(small_physical, **kwargs)
    assert assumed["photometric_response"] == {"mode": "gamma"}
    fits = measured["photometric_response"]
    assert fits["mode"] == "measured" and fits["fitted"] + fits["refused"] == 6 and fits["fitted"] >= 4
    scores = measured["results"][0]["photo_psnr"], assumed["results"][0]["photo_psnr"]
    assert abs(scores[0] - scores[1]) < 0.3, scores
    paper = run_bench(tiny_train, limit=2, response="measured", **kwargs)["photometric_response"]
    assert paper["fitted"] == 2  # the paper's blend is linear: exponent 1 where identified, else gamma 1 kept


def test_response_needs_the_photometric_loop(tiny_train):
    with pytest.raises(ProjregError, match="--response chooses the photometric model's device curves"):
        run_bench(tiny_train, baselines=("dis-medium",), compensation=True, response="measured")
    with pytest.raises(ProjregError, match="--response must be one of gamma, measured"):
        run_bench(tiny_train, baselines=("dis-medium",), compensation=True, photometric=True, response="both")
