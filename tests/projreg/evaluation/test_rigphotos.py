"""``bench --photos``: each model again on the capture divided by the sample's own white and black photos."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.cli import app
from projreg.evaluation.bench import run_bench
from projreg.evaluation.closedloop import UNCOMPENSATED
from projreg.evaluation.methods import Method
from projreg.evaluation.rigphotos import RigPhotos
from projreg.inference.photos import normalise_capture
from projsynth.dataset.rerender import Rerenderer
from projsynth.dataset.shards import ShardReader


def test_the_photos_are_the_samples_own_noiseless_white_and_black_and_divide_the_capture(tiny_physical):
    reader, rig, seen = ShardReader(tiny_physical), RigPhotos(tiny_physical), []
    spy = Method("spy", "model", lambda a, b: seen.append(b) or np.zeros((*a.shape[:2], 2), np.float32), True)
    tracking = Method("spy+track", "model", spy.predict, True, tracker=object())
    baseline = Method("dis", "baseline", spy.predict)
    divided = rig.methods([spy, tracking, baseline])
    assert [(m.name, m.kind, m.refined) for m in divided] == [("spy+photos", "model", True)]
    s = reader.read(2)
    rig.shoot(2, s)
    white, black = Rerenderer(tiny_physical).views(
        2, [np.full_like(s["projected"], 255), s["projected"] * 0], noise=False
    )
    divided[0].predict(s["projected"], s["captured"])
    np.testing.assert_array_equal(seen[0], normalise_capture(s["captured"], white.image, black.image))
    assert (white.image >= black.image).all() and white.image.mean() > black.image.mean() + 10  # no noise: light adds


def test_bench_photos_rows_claim_more_of_a_daylit_textured_wall_and_enter_the_compensation(small_physical):
    report = run_bench(small_physical, baselines=(), photos=True, compensation=True)
    rows = {r["name"]: r for r in report["results"]}
    assert list(rows) == ["reference", "reference+photos", UNCOMPENSATED]
    plain, photos = rows["reference"], rows["reference+photos"]
    assert photos["kind"] == "model" and photos["pixels"] == plain["pixels"]  # the same truth
    assert photos["claimed"] > plain["claimed"] and photos["epe"] < plain["epe"]
    assert photos["comp_psnr"] is not None and photos["comp_psnr"] > rows[UNCOMPENSATED]["comp_psnr"]


def test_bench_photos_cli_writes_the_rows_and_refuses_what_it_cannot_render(tiny_train, tmp_path, one_line_error):
    out = tmp_path / "report.json"
    args = ["bench", "--data", str(tiny_train), "--baselines", "none", "--limit", "2", "--photos", "-q"]
    result = CliRunner().invoke(app, [*args, "--json", str(out)])
    assert result.exit_code == 0, (result.stderr, result.exception)
    assert [r["name"] for r in json.loads(out.read_text())["results"]] == ["reference", "reference+photos"]
    assert "reference+photos" in result.stdout
    (tmp_path / "captured").mkdir()
    (tmp_path / "captured" / "dataset.json").write_text('{"captured": {}}')
    with pytest.raises(ProjregError, match=r"^--photos: .*a captured dataset \(photographs\) cannot be re-rendered"):
        RigPhotos(tmp_path / "captured")
    result = CliRunner().invoke(app, [*args, "--track"])
    one_line_error(result, "--photos registers single pairs; drop --track")
