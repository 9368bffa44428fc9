"""The in-memory API gives what the command line writes, pair by pair, batch or not, any camera size."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.api import Registrar, compensate, end_point_error, export_warp
from projreg.cli import app
from projreg.inference.compensate import compensate as compensate_arrays
from projreg.inference.photos import normalise_capture
from projsynth.flow.formats import read_flow_exr, read_flow_file
from projsynth.structured.response import Response, projector_curve, response_record


def _png(path, rgb):
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return str(path)


def test_register_gives_predicts_flow_and_valid_for_any_camera_size(pairs, tiny_ckpt, tmp_path):
    img0, img1 = pairs[0]
    bigger = cv2.resize(img1, (144, 96), interpolation=cv2.INTER_LINEAR)  # a camera 1.5x the projector
    registrar = Registrar(tiny_ckpt, device="cpu")
    for name, captured in (("same", img1), ("bigger", bigger)):
        reg = registrar.register(img0, captured)
        out = tmp_path / f"{name}.exr"
        args = ["--projected", _png(tmp_path / "p.png", img0), "--captured", _png(tmp_path / f"{name}.png", captured)]
        result = CliRunner().invoke(app, ["predict", *args, "--out", str(out), "--model", str(tiny_ckpt), "-q"])
        assert result.exit_code == 0, result.stderr
        flow, valid, header = read_flow_exr(out)
        np.testing.assert_array_equal(read_flow_file(out).confidence, reg.confidence)  # the confidence beside the claim
        assert np.isfinite(reg.flow).all()
        np.testing.assert_allclose(reg.flow, flow, atol=1e-4)
        np.testing.assert_array_equal(reg.claimed, valid)
        assert reg.camera_size == captured.shape[:2] and header["camera_size"] == "x".join(map(str, reg.camera_size))
        assert reg.confidence is not None and set(reg.timings) == {"network", "refine"}
    batch = registrar.register_batch(pairs, batch_size=2)
    for (a, b), reg in zip(pairs, batch, strict=True):
        np.testing.assert_allclose(reg.flow, registrar.register(a, b).flow, atol=1e-4)


def test_compensate_is_the_pre_warp_of_the_whole_flow_or_of_the_claim(pairs, tiny_ckpt):
    img0, img1 = pairs[1]
    reg = Registrar(tiny_ckpt, device="cpu").register(img0, img1)
    reg = replace(reg, registered=True)  # the tiny test network may not register; the coverage is the point here
    wanted = np.full_like(img1, 200)
    wanted[:, ::8] = 30
    complete = compensate_arrays(wanted, reg.flow, None, 7, camera_size=reg.camera_size)
    np.testing.assert_array_equal(compensate(wanted, reg, fill=7), complete)
    claimed = compensate_arrays(
        wanted,
        replace(reg, flow=np.where(reg.claimed[..., None], reg.flow, 0)).flow,
        reg.claimed,
        7,
        camera_size=reg.camera_size,
    )
    np.testing.assert_array_equal(compensate(wanted, reg, fill=7, coverage="claimed"), claimed)
    confident = reg.confidence >= 0.3
    np.testing.assert_array_equal(
        compensate(wanted, reg, fill=7, min_confidence=0.3),
        compensate_arrays(wanted, reg.flow, confident, 7, camera_size=reg.camera_size),
    )
    unregistered = compensate(wanted, replace(reg, registered=False))
    np.testing.assert_array_equal(unregistered, cv2.resize(wanted, img0.shape[1::-1], interpolation=cv2.INTER_AREA))
    with pytest.raises(ProjregError, match="both the white and the black"):
        compensate(wanted, reg, white=img1)


def test_compensate_takes_the_measured_response_as_an_object_or_a_file(pairs, tiny_ckpt, tmp_path):
    img0, img1 = pairs[1]
    reg = Registrar(tiny_ckpt, device="cpu").register(img0, img1)
    wanted, white, black = np.full_like(img1, 120), np.full_like(img1, 230), np.full_like(img1, 20)
    levels = (0, 64, 128, 191, 255)
    points = np.tile((np.array(levels) / 255) ** 2.6, (3, 1))
    curves = Response(1.8, projector_curve(levels, points), True, (1.7, 1.9), levels, points, 1.0, 100)
    (tmp_path / "r.json").write_text(json.dumps(response_record(curves)))
    photos = {"white": white, "black": black}
    by_object = compensate(wanted, reg, **photos, response=curves)
    np.testing.assert_array_equal(compensate(wanted, reg, **photos, response=tmp_path / "r.json"), by_object)
    assert not np.array_equal(by_object, compensate(wanted, reg, **photos))  # gamma 2.2 assumed: another image
    with pytest.raises(ProjregError, match="give one of the two"):
        compensate(wanted, reg, **photos, response=curves, gamma=2.2)
    with pytest.raises(ProjregError, match="give the white and black photos"):
        compensate(wanted, reg, response=curves)


def test_the_network_alone_claims_everything_and_bad_input_is_one_line(pairs, tiny_ckpt):
    img0, img1 = pairs[0]
    raw = Registrar(tiny_ckpt, device="cpu", refine=False).register(img0, img1)
    assert raw.claimed.all() and raw.confidence is None and set(raw.timings) == {"network"}
    with pytest.raises(ProjregError, match=r"^captured: expected a uint8 RGB array \(H, W, 3\)"):
        Registrar(tiny_ckpt, device="cpu").register(img0, img1.astype(np.float32))
    with pytest.raises(ProjregError, match="--quality 'slow'"):
        Registrar(tiny_ckpt, device="cpu", quality="slow")
    with pytest.raises(ProjregError, match="tracking follows each frame with the refinement"):
        next(Registrar(tiny_ckpt, device="cpu", refine=False).track([(img0, img1)]))


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_end_point_error_refuses_a_flow_that_is_not_finite_where_it_is_scored(bad):
    truth, valid = np.zeros((4, 5, 2), np.float32), np.ones((4, 5), bool)
    flow = truth.copy()
    flow[1, 2] = bad
    with pytest.raises(ProjregError, match=r"^flow: 1 valid pixel\(s\) hold NaN or Inf"):
        end_point_error(flow, truth, valid)
    valid[1, 2] = False  # where it is not scored, anything goes
    assert end_point_error(flow, truth, valid)["epe"] == 0.0


def test_predict_then_compensate_on_the_command_line_is_the_api_s_compensation(pairs, tiny_ckpt, tmp_path):
    img0, img1 = pairs[0]
    reg = Registrar(tiny_ckpt, device="cpu").register(img0, img1)
    wanted = cv2.GaussianBlur(np.random.default_rng(2).integers(0, 255, img1.shape, np.uint8), (0, 0), 2)
    args = ["--projected", _png(tmp_path / "p.png", img0), "--captured", _png(tmp_path / "c.png", img1)]
    assert (
        CliRunner()
        .invoke(app, ["predict", *args, "--out", str(tmp_path / "f.exr"), "--model", str(tiny_ckpt), "-q"])
        .exit_code
        == 0
    )
    for extra, kwargs in (([], {}), (["--coverage", "claimed"], {"coverage": "claimed"})):
        out = tmp_path / f"out{len(extra)}.png"
        cmd = ["compensate", "--content", _png(tmp_path / "w.png", wanted), "--flow", str(tmp_path / "f.exr")]
        result = CliRunner().invoke(app, [*cmd, "--out", str(out), *extra])
        if kwargs and not reg.claimed.any():
            assert result.exit_code == 2  # nothing claimed: nothing to show
            continue
        assert result.exit_code == 0, result.stderr
        written = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(written, compensate(wanted, reg, **kwargs))


def rig_photos(captured):
    """Photos a rig could take of the scene behind ``captured``: a white brighter, a black darker."""
    lift = captured.astype(np.int16)
    return np.clip(lift + 60, 0, 255).astype(np.uint8), np.clip(lift // 3, 0, 255).astype(np.uint8)


def test_register_with_the_rigs_photos_registers_the_capture_with_the_surface_divided_out(pairs, tiny_ckpt):
    img0, img1 = pairs[0]
    white, black = rig_photos(img1)
    registrar = Registrar(tiny_ckpt, device="cpu")
    for photos in ({"white": white, "black": black}, {"white": white}):
        divided = normalise_capture(img1, **photos)
        assert not np.array_equal(divided, img1)
        expected = registrar.register(img0, divided)
        for reg in (
            registrar.register(img0, img1, **photos),
            *registrar.register_batch([(img0, img1)] * 2, batch_size=2, **photos),
            next(registrar.track([(img0, img1)], **photos)),
        ):
            np.testing.assert_allclose(reg.flow, expected.flow, atol=1e-4)
            np.testing.assert_array_equal(reg.claimed, expected.claimed)
    with pytest.raises(ProjregError, match=r"^--black needs --white"):
        registrar.register(img0, img1, black=black)
    with pytest.raises(ProjregError, match=r"^--white is 48x32 px but the captured image is 96x64"):
        registrar.register(img0, img1, white=white[::2, ::2])
    with pytest.raises(ProjregError, match=r"^white: expected a uint8 RGB array"):
        registrar.register(img0, img1, white=white.astype(np.float32))


def test_bad_batches_frames_and_options_are_one_line_naming_the_argument(pairs, tiny_ckpt):
    img0, img1 = pairs[0]
    registrar = Registrar(tiny_ckpt, device="cpu")
    cases = [
        (lambda: registrar.register_batch([img0, img1]), r"^pairs\[0\]: expected a \(projected, captured\) pair"),
        (lambda: registrar.register_batch([(img0, img1, img1)]), r"^pairs\[0\]: .* got 3 items"),
        (lambda: registrar.register_batch([(img0, img1)], batch_size=1.5), r"^batch_size: expected an integer"),
        (lambda: registrar.register_batch([(img0, img1), (img0, img1[..., 0])]), r"^pairs\[1\] captured: expected"),
        (lambda: Registrar(model=123), r"^model: expected None, 'reference' or a path, got int"),
        (lambda: Registrar(tiny_ckpt, max_side=16.5), r"^max_side: expected an integer >= 16"),
        (lambda: registrar.track(None), r"^frames: expected an iterable"),
        (
            lambda: registrar.register(np.zeros((0, 0, 3), np.uint8), img1),
            r"^projected: 0x0 px; .* at least 8 px a side",
        ),
        (lambda: registrar.register(img0, np.zeros((1, 1, 3), np.uint8)), r"^captured: 1x1 px"),
        (lambda: next(registrar.track([img0])), r"^frames\[0\]: expected a \(projected, captured\) pair"),
        (lambda: compensate(img1, reg_flow_only), r"^registration: expected a Registration"),
        (lambda: compensate(img1, registration, fill=300), r"^fill: must be an integer in 0..255"),
        (lambda: compensate(img1, registration, fill=-1), r"^fill: must be an integer in 0..255"),
        (lambda: compensate(img1, registration, fill=True), r"^fill: must be an integer in 0..255, got True"),
        (lambda: registrar.live(img1, img0, fill=True), r"^fill: must be an integer in 0..255, got True"),
        (lambda: Registrar(tiny_ckpt, refine="no"), r"^refine: expected True or False, got 'no'"),  # was on
        (lambda: Registrar(tiny_ckpt, refine=None), r"^refine: expected True or False, got None"),  # was off
        (lambda: registrar.live(0, img0, predict_motion="no"), r"^predict_motion: expected True or False"),
        (lambda: registrar.live(-1, img0), r"^captured -1: a camera index is in 0..9999"),  # crashed OpenCV
        (lambda: registrar.live(99_999_999_999, img0), r"^captured 99999999999: a camera index is in 0..9999"),
        (lambda: registrar.live("", img0), r"^captured: empty"),
        (lambda: Registrar(""), r"^model: empty; give a path"),  # not the current folder
        (lambda: registrar.register(img0, img1, response=""), r"^response: empty; give a path"),
        (lambda: export_warp("", "warp.exr"), r"^source: empty; give a path"),
        (lambda: registrar.live(0, img0.astype(np.float32)), r"^content: expected a uint8 RGB array"),
        (  # 0 is a value, not "unset": refused, not read as the default 2.2
            lambda: compensate(img1, registration, white=img1, black=img1 // 4, gamma=0),
            r"^--gamma: expected a display/camera gamma",
        ),
        (
            lambda: compensate(np.zeros((0, 0, 3), np.uint8), registration),
            r"^content: 0x0 px; an image needs at least 8 px",
        ),
    ]
    registration = registrar.register(img0, img1)
    reg_flow_only = registration.flow
    for call, says in cases:
        with pytest.raises(ProjregError, match=says):
            call()
    assert len(registrar.register_batch(pair for pair in [(img0, img1)] * 2)) == 2  # any iterable, read once
