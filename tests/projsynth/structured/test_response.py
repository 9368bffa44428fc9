"""The devices' response fitted from photos of grey levels: against an analytic camera, against the virtual
rig's known curves, and refused with one line when the photos cannot say."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from projsynth import ProjsynthError
from projsynth.dataset.transforms import TransformTable, builtin_table
from projsynth.structured.capture import make_rig, shoot
from projsynth.structured.patterns import make_set, write_patterns
from projsynth.structured.response import (
    FALLBACK_EXPONENT,
    Response,
    fit_folder,
    fit_response,
    read_response,
)

LEVELS = tuple(make_set("response", (32, 32)).params["levels"])
CODES = np.arange(256) / 255


def analytic_photos(exponent, gammas, ratio, seed=0, pixels=(60, 80), noise=1.0, exposure=1.0):
    """A camera written here: ``C = 255 (a (r + g_c(l)))^(1/exponent)`` + noise, 8-bit, where ``a`` (albedo
    times the projector's light) and ``r`` (the room's light against the projector's) vary per pixel."""
    rng = np.random.default_rng(seed)
    a = exposure * rng.uniform(0.15, 0.8, (*pixels, 1))
    r = rng.uniform(*ratio, (*pixels, 1))
    g = (np.asarray(LEVELS)[:, None] / 255) ** np.asarray(gammas)[None]  # (K, 3)
    lin = a[None] * (r[None] + g[:, None, None, :])
    c = 255 * np.clip(lin, 0, 1) ** (1 / exponent) + rng.normal(0, noise, lin.shape)
    return np.clip(np.rint(c), 0, 255).astype(np.float32) / 255


def curve_errors(response, exponent, gammas):
    """Max and mean absolute error over code values 0..255 of the normalised camera curve ``F^-1`` and of
    the projector's curves, against the truth."""
    camera = np.abs(CODES**response.camera_exponent - CODES**exponent)
    projector = np.abs(response.projector - CODES[None] ** np.asarray(gammas)[:, None])
    return camera.max(), camera.mean(), projector.max(), projector.mean()


def test_an_analytic_camera_is_recovered_where_the_room_light_varies_against_the_projector():
    gammas = (2.0, 2.2, 2.5)  # a projector whose channels differ
    r = fit_response(LEVELS, analytic_photos(2.4, gammas, ratio=(0.02, 0.6)))
    assert r.identified and abs(r.camera_exponent - 2.4) < 0.05, (r.camera_exponent, r.interval)
    assert r.interval[0] <= 2.4 <= r.interval[1]
    cam_max, cam_mean, proj_max, proj_mean = curve_errors(r, 2.4, gammas)
    assert cam_max < 0.01 and proj_max < 0.01, (cam_max, proj_max)
    assert r.rms_dn < 1.2  # the camera's noise (1 DN) and its 8-bit rounding


def test_a_constant_proportion_of_room_light_leaves_the_camera_unidentified_but_the_photos_explained():
    """A dark room: ``o_p / a_p`` the same everywhere; every exponent explains the photos, so the fallback is
    kept and the projector's curve bends to reproduce them (``g^(exponent / fallback)`` here)."""
    r = fit_response(LEVELS, analytic_photos(2.0, (2.2, 2.2, 2.2), ratio=(0.0, 0.0)), fallback=FALLBACK_EXPONENT)
    assert not r.identified and r.camera_exponent == FALLBACK_EXPONENT
    assert r.interval[1] - r.interval[0] > 0.5
    composite = CODES ** (2.2 * FALLBACK_EXPONENT / 2.0)
    assert np.abs(r.projector - composite).max() < 0.01


def scene_with_room_light_varying(table: TransformTable, ids: list[int]) -> TransformTable:
    """``table`` with the transparency field of ``ids`` spanning 0.05-0.95 under a fixed room light: the
    projector's light falls off across the surface while the room's does not."""
    configs = list(table.configs)
    for t in ids:
        light = {**configs[t].photometry, "alpha": (0.5, 0.5), "alpha_var": (0.45, 0.45), "ambient": (0.1, 0.1)}
        configs[t] = replace(configs[t], photometry=light)
    return TransformTable("room-light-varies", tuple(configs))


def rig_photos(table, tid, size=(96, 128), seed=3):
    rig = make_rig(table, tid, seed, size, size)
    images = make_set("response", size).images()
    return rig, np.stack([shoot(rig, img, seed, i) for i, img in enumerate(images)])


@pytest.mark.parametrize("tid", [0, 4])  # studio; noisy (read noise 3-8 DN, gain 2-4)
def test_the_virtual_rig_s_known_curves_are_recovered(tid):
    """The simulated camera's response exponent (2.0-2.4, drawn) and the projector's gamma 2.2."""
    rig, photos = rig_photos(scene_with_room_light_varying(builtin_table(), [tid]), tid)
    r = fit_response(LEVELS, photos.astype(np.float32) / 255)
    truth = rig.photometry["response"]
    assert r.identified and abs(r.camera_exponent - truth) < 0.06, (r.camera_exponent, truth, r.interval)
    cam_max, _, proj_max, _ = curve_errors(r, truth, (2.2, 2.2, 2.2))
    assert cam_max < 0.012 and proj_max < 0.01, (cam_max, proj_max)


def test_the_virtual_rig_s_default_scenes_fall_back_and_still_predict_the_photos():
    """The built-in table's transparency barely varies, so the room light's proportion is nearly constant:
    the fit says so, keeps the fallback and still predicts each level's photo from the black and white
    ones without bias, where gamma 2.2 for both devices is off by 1.5 DN at some level (response 2.02)."""
    rig, photos = rig_photos(builtin_table(), 0)
    r = fit_response(LEVELS, photos.astype(np.float32) / 255)
    assert not r.identified and r.camera_exponent == FALLBACK_EXPONENT
    lit = ((photos[-1].astype(int) - photos[0]).min(axis=2) > 13) & (photos[-1] < 250).all(axis=2)

    def worst_bias(curves: Response) -> float:
        levels = enumerate(LEVELS[1:-1], start=1)
        return max(abs(float((curves.predict(photos[0], photos[-1], v) - photos[k])[lit].mean())) for k, v in levels)

    assert worst_bias(r) < 0.3 < 1.0 < worst_bias(Response.from_gamma(2.2)), (worst_bias(r), rig.photometry)


def test_the_curves_invert():
    r = fit_response(LEVELS, analytic_photos(2.2, (1.8, 2.2, 2.6), ratio=(0.02, 0.6)))
    codes = np.arange(256, dtype=np.uint8)[:, None].repeat(3, axis=1)
    np.testing.assert_array_equal(r.projector_codes(r.projector_linear(codes)), codes)
    assert (np.diff(r.projector, axis=1) > 0).all()
    gamma = Response.from_gamma(2.2)
    np.testing.assert_allclose(gamma.camera_linear(codes), (codes / 255) ** 2.2, rtol=1e-5)


REFUSED = {
    "blank": (lambda p: np.zeros_like(p), "barely differ"),
    "clipped": (lambda p: np.clip(p * 1.8, 0, 1), "clipped on"),
    "out of order": (lambda p: p[[0, 1, 2, 3, 4, 5, 6, 7, 12, 9, 10, 11, 8, 13, 14, 15, 16]], "darker than"),
}


@pytest.mark.parametrize("case", REFUSED)
def test_photos_that_cannot_say_are_refused(case):
    change, needle = REFUSED[case]
    photos = analytic_photos(2.2, (2.2, 2.2, 2.2), ratio=(0.02, 0.6))
    with pytest.raises(ProjsynthError, match=needle):
        fit_response(LEVELS, change(photos))


@pytest.fixture
def shot(tmp_path):
    """A response set of 17 levels and its photos by the analytic camera, as PNG files; and the photos."""
    patterns = make_set("response", (60, 80))
    write_patterns(patterns, tmp_path / "pat")
    photos = analytic_photos(2.2, (2.0, 2.2, 2.4), ratio=(0.02, 0.6))
    (tmp_path / "shots").mkdir()
    for name, photo in zip(patterns.names, photos, strict=True):
        rgb = np.rint(photo * 255).astype(np.uint8)
        cv2.imwrite(str(tmp_path / "shots" / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return tmp_path, photos


def test_the_file_round_trip_and_edits_refused(shot):
    root, photos = shot
    out = root / "cal" / "response.json"
    line = fit_folder(root / "pat", root / "shots", out)
    assert "camera exponent 2.2" in line and "17 levels" in line, line
    record = json.loads(out.read_text())
    assert record["fit"]["camera_size"] == [60, 80] and len(record["fit"]["photos"]) == 17
    back, fitted = read_response(out), fit_response(LEVELS, photos)
    np.testing.assert_allclose(back.projector, fitted.projector, atol=2e-6)  # the file keeps 6 decimals
    assert back.camera_exponent == fitted.camera_exponent and back.identified and back.interval == fitted.interval
    record["projector"]["points"][1][3] = 0.9  # G falls after level 48
    out.write_text(json.dumps(record))
    with pytest.raises(ProjsynthError, match="rising"):
        read_response(out)
    record["format_version"] = 9
    out.write_text(json.dumps(record))
    with pytest.raises(ProjsynthError, match="not a response file"):
        read_response(out)


def test_folders_that_cannot_be_fitted_are_refused_and_nothing_written(shot):
    shot, _ = shot
    out = shot / "response.json"
    (shot / "shots" / "00-level000.png").unlink()
    with pytest.raises(ProjsynthError, match="no photo of pattern 00-level000"):
        fit_folder(shot / "pat", shot / "shots", out)
    cv2.imwrite(str(shot / "shots" / "00-level000.png"), np.zeros((30, 40, 3), np.uint8))
    with pytest.raises(ProjsynthError, match="all photos must come from one camera"):
        fit_folder(shot / "pat", shot / "shots", out)
    write_patterns(make_set("dots", (60, 80), grid=(4, 4)), shot / "dots")
    with pytest.raises(ProjsynthError, match="a dots set"):
        fit_folder(shot / "dots", shot / "shots", out)
    with pytest.raises(ProjsynthError, match="one JSON file"):
        fit_folder(shot / "pat", shot / "shots", shot / "cal")
    assert not out.exists()
