"""The in-memory API gives what the command line writes, pair by pair, batch or not, any camera size."""

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from projreg import ProjregError
from projreg.api import Registrar, compensate
from projreg.cli import app
from projreg.inference.compensate import compensate as compensate_arrays
from projsynth.flow.formats import read_flow_exr
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
        np.testing.assert_allclose(reg.flow, flow, atol=1e-4)
        np.testing.assert_array_equal(reg.claimed, valid)
        assert reg.camera_size == captured.shape[:2] and header["camera_size"] == "x".join(map(str, reg.camera_size))
        assert reg.confidence is not None and set(reg.timings) == {"network", "refine"}
    batch = registrar.register_batch(pairs, batch_size=2)
    for (a, b), reg in zip(pairs, batch, strict=True):
        np.testing.assert_allclose(reg.flow, registrar.register(a, b).flow, atol=1e-4)


def test_compensate_is_the_pre_warp_of_the_claimed_flow(pairs, tiny_ckpt):
    img0, img1 = pairs[1]
    reg = Registrar(tiny_ckpt, device="cpu").register(img0, img1)
    wanted = np.full_like(img1, 200)
    wanted[:, ::8] = 30
    expected = compensate_arrays(wanted, reg.flow, reg.claimed, 7, camera_size=reg.camera_size)
    np.testing.assert_array_equal(compensate(wanted, reg, fill=7), expected)
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
