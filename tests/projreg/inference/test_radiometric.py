"""Photometric compensation on a camera model written here: per-pixel gain and offset, gamma 2.2, or a
camera and a projector of other curves, measured."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.cli import app
from projreg.evaluation.bench import run_bench
from projreg.inference.radiometric import calibrate, solve, to_linear
from projsynth.structured.response import Response


def camera(projector: np.ndarray, offset: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """What this test's camera photographs: ``offset + gain * projector_lin``, gamma 2.2 both ways."""
    lin = offset + gain * to_linear(projector, 2.2)
    return np.clip(np.rint(255 * np.clip(lin, 0, 1) ** (1 / 2.2)), 0, 255).astype(np.uint8)


def test_solve_makes_the_camera_show_the_wanted_view_on_a_textured_surface():
    rng = np.random.default_rng(0)
    h, w = 48, 64
    albedo = rng.uniform(0.3, 1.0, (h, w, 3)).astype(np.float32)  # a textured, coloured surface
    offset, gain = 0.08 * albedo, 0.8 * albedo
    wanted = rng.integers(40, 220, (h, w, 3), dtype=np.uint8)
    model = calibrate(
        camera(np.full((h, w, 3), 255, np.uint8), offset, gain), camera(np.zeros((h, w, 3), np.uint8), offset, gain)
    )
    need, scale = solve(wanted, model)
    seen = to_linear(camera(need, offset, gain), 2.2)
    plain = to_linear(camera(wanted, offset, gain), 2.2)
    target = to_linear(wanted, 2.2)
    # up to one global brightness and contrast, the compensated view is the wanted one; the plain one is not
    fit = lambda v: np.polyfit(target.ravel(), v.ravel(), 1)  # noqa: E731
    residual = lambda v: np.abs(np.polyval(fit(v), target) - v)  # noqa: E731
    assert np.median(residual(seen)) < 0.01 < np.median(residual(plain))
    assert 0 < scale <= 0.8


def test_measured_curves_compensate_a_camera_and_projector_that_are_not_gamma_2_2():
    """A camera of exponent 1.6 (F^-1(c) = c^1.6) and a projector of gamma 2.6: with their curves the
    compensated view is the wanted one (in the camera's linear light, up to one brightness and contrast),
    with gamma 2.2 assumed for both it is several times further off."""
    rng = np.random.default_rng(1)
    h, w = 48, 64
    albedo = rng.uniform(0.3, 1.0, (h, w, 3)).astype(np.float32)
    offset, gain = 0.06 * albedo, 0.8 * albedo

    def shoot(projector: np.ndarray) -> np.ndarray:
        lin = offset + gain * (projector / 255.0) ** 2.6
        return np.clip(np.rint(255 * np.clip(lin, 0, 1) ** (1 / 1.6)), 0, 255).astype(np.uint8)

    white, black = shoot(np.full((h, w, 3), 255, np.uint8)), shoot(np.zeros((h, w, 3), np.uint8))
    wanted = rng.integers(40, 220, (h, w, 3), dtype=np.uint8)
    codes = np.arange(256) / 255
    measured = Response(1.6, np.tile(codes**2.6, (3, 1)).astype(np.float32))
    target = (wanted / 255.0) ** 1.6

    def off(model) -> float:
        seen = (shoot(solve(wanted, model)[0]) / 255.0) ** 1.6
        fit = np.polyfit(target.ravel(), seen.ravel(), 1)
        return float(np.median(np.abs(np.polyval(fit, target) - seen)))

    exact, assumed = off(calibrate(white, black, response=measured)), off(calibrate(white, black))
    assert exact < 0.005 and assumed > 3 * exact, (exact, assumed)


def test_calibration_refuses_mismatched_photos():
    with pytest.raises(ProjregError, match="--white"):
        calibrate(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8))


def test_bench_photometric_beats_geometric_only(small_physical):
    report = run_bench(small_physical, baselines=(), compensation=True, photometric=True)
    model = report["results"][0]
    assert model["photo_psnr"] > model["geo_psnr"] and model["photo_de2000"] < model["geo_de2000"]
    assert report["results"][-1]["photo_psnr"] is None  # uncompensated: no photometric row


def test_compensate_photometric_needs_both_photos(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "compensate",
            "--content",
            "a.png",
            "--flow",
            "f.exr",
            "--out",
            str(tmp_path / "o.png"),
            "--photometric",
            "--white",
            "w.png",
        ],
    )
    assert result.exit_code == 2 and "--black" in result.stderr


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--response", "r.json"], "--response sets the photometric correction; add --photometric"),
        (["--gamma", "2.4"], "--gamma sets the photometric correction; add --photometric"),
        (
            ["--photometric", "--white", "w.png", "--black", "b.png", "--response", "r.json", "--gamma", "2"],
            "drop --gamma",
        ),
    ],
)
def test_compensate_response_options_are_checked(tmp_path, extra, needle, one_line_error):
    args = ["compensate", "--content", "a.png", "--flow", "f.exr", "--out", str(tmp_path / "o.png"), *extra]
    one_line_error(CliRunner().invoke(app, args), needle)
    assert not (tmp_path / "o.png").exists()


def photometric_args(tiny_physical, folder) -> list[str]:
    """``compensate --photometric`` on sample 0 of ``tiny_physical``: its picture, its truth, its rig's
    white and black photos, written to ``folder``; ``--out folder/o.png``."""
    import cv2

    from projsynth.dataset.rerender import Rerenderer
    from projsynth.dataset.shards import ShardReader
    from projsynth.flow.formats import write_flow_exr

    s = ShardReader(tiny_physical).read(0)
    white, black = Rerenderer(tiny_physical).views(
        0, [np.full_like(s["projected"], 255), np.zeros_like(s["projected"])]
    )
    write_flow_exr(folder / "f.exr", s["flow"], s["valid"], "truth")
    for name, image in (("a", s["projected"]), ("w", white.image), ("b", black.image)):
        cv2.imwrite(str(folder / f"{name}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    args = ["compensate", "--content", str(folder / "a.png"), "--flow", str(folder / "f.exr")]
    return [
        *args,
        "--out",
        str(folder / "o.png"),
        "--photometric",
        "--white",
        str(folder / "w.png"),
        "--black",
        str(folder / "b.png"),
    ]


def test_compensate_reads_a_response_file(tiny_physical, tmp_path):
    """A measured response that is gamma 2.2 for both devices gives gamma 2.2's projector image, to the
    code value (the curve through 17 levels and its inverse)."""
    import cv2

    from projsynth.structured.response import projector_curve, response_record

    levels = tuple(int(v) for v in np.rint(np.linspace(0, 255, 17)))
    points = np.tile((np.array(levels) / 255) ** 2.2, (3, 1))
    curves = Response(2.2, projector_curve(levels, points), True, (2.1, 2.3), levels, points, 1.0, 100)
    (tmp_path / "r.json").write_text(json.dumps(response_record(curves)))
    args = photometric_args(tiny_physical, tmp_path)
    shown, lines = [], []
    for extra in (["--response", str(tmp_path / "r.json")], []):
        result = CliRunner().invoke(app, [*args, *extra])
        assert result.exit_code == 0, result.stderr
        shown.append(cv2.imread(str(tmp_path / "o.png")).astype(int))
        lines.append(result.stderr)
    assert "with the measured response" in lines[0] and "measured" not in lines[1]
    assert np.abs(shown[0] - shown[1]).max() <= 1 and (shown[0] != shown[1]).mean() < 0.01


def test_compensate_refuses_a_response_file_that_is_not_one(tiny_physical, tmp_path, one_line_error):
    bad = tmp_path / "r.json"
    bad.write_text('{"format_version": 1, "camera": {"exponent": 2.2}, "projector": {"levels": [0, 255]}}')
    args = [*photometric_args(tiny_physical, tmp_path), "--response", str(bad)]
    one_line_error(CliRunner().invoke(app, args), bad, "not a response file")
    assert not (tmp_path / "o.png").exists()


def test_compensate_photometric_end_to_end(tiny_physical, tmp_path):
    """As a user runs it: the rig's white and black photos, a flow EXR and the wanted view in; on every
    sample the camera's view of the written projector image is closer to the wanted view than that of
    geometric compensation alone (by 1 dB on average)."""
    import cv2

    from projreg.evaluation.closedloop import compared_region, desired_scores
    from projsynth.dataset.rerender import Rerenderer
    from projsynth.dataset.shards import ShardReader
    from projsynth.flow.formats import write_flow_exr

    reader, rerender = ShardReader(tiny_physical), Rerenderer(tiny_physical)
    gains = []
    for k in range(len(reader)):
        s = reader.read(k)
        white, black = rerender.views(k, [np.full_like(s["projected"], 255), np.zeros_like(s["projected"])])
        files = {name: tmp_path / f"{name}.png" for name in ("wanted", "white", "black")}
        for name, image in (("wanted", s["projected"]), ("white", white.image), ("black", black.image)):
            cv2.imwrite(str(files[name]), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        write_flow_exr(tmp_path / "flow.exr", s["flow"], s["valid"], "truth")
        photometric = ["--photometric", "--white", str(files["white"]), "--black", str(files["black"])]
        shown = []
        for mode, extra in (("geo", []), ("photo", photometric)):
            out = tmp_path / f"{mode}.png"
            args = [
                "compensate",
                "--content",
                str(files["wanted"]),
                "--flow",
                str(tmp_path / "flow.exr"),
                "--out",
                str(out),
                *extra,
            ]
            result = CliRunner().invoke(app, args)
            assert result.exit_code == 0, result.stderr
            shown.append(cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB))
        views = rerender.views(k, shown)
        region = compared_region(rerender.views(k, [s["projected"]])[0], s["valid"])
        geo, photo = (desired_scores(v.image, s["projected"], region, 2.2, "x")["x_psnr"] for v in views)
        gains.append(photo - geo)
    assert min(gains) > 0 and np.mean(gains) > 1.0, gains
