"""Defects 7 and 11: `compensate` with non-finite flow, and outputs that are one of the inputs."""

import os

import cv2
import numpy as np
import pytest

from projsynth.flow.formats import write_flow_exr

H, W = 48, 64


@pytest.fixture
def content(tmp_path):
    image = np.random.default_rng(0).integers(0, 255, (H, W, 3), np.uint8)
    path = tmp_path / "content.png"
    assert cv2.imwrite(str(path), image)
    return path


def _flow(tmp_path, bad: float, where: slice) -> tuple:
    flow = np.zeros((H, W, 2), np.float32)
    flow[where] = bad
    write_flow_exr(tmp_path / "f.exr", flow, np.ones((H, W), bool), "probe")
    return tmp_path / "f.exr"


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_flow_is_filled_like_invalid_flow(probe, tmp_path, content, bad):
    flow = _flow(tmp_path, bad, np.s_[:, :10, 0])
    out = tmp_path / "p.png"
    result = probe.projreg("compensate", "--content", content, "--flow", flow, "--out", out, "--fill", "200")
    assert result.exit_code == 0, result.stderr
    projector = cv2.imread(str(out))
    assert (projector[:, :10] == 200).all()  # before the fix: 0 (NaN/Inf through cv2.remap)
    np.testing.assert_array_equal(projector[:, 10:], cv2.imread(str(content))[:, 10:])  # zero flow elsewhere


def test_a_flow_with_no_finite_vector_is_refused(probe, tmp_path, content):
    flow = _flow(tmp_path, np.nan, np.s_[:, :, 1])
    out = tmp_path / "p.png"
    probe.error(
        probe.projreg("compensate", "--content", content, "--flow", flow, "--out", out), flow, "no finite valid vector"
    )
    assert not out.exists()


def _same_file_cases(tmp_path, path):
    """The input's own path, another spelling of it, and a hard link to it."""
    os.link(path, tmp_path / "link.png")
    (tmp_path / "sub").mkdir(exist_ok=True)
    return [path, tmp_path / "sub" / ".." / path.name, tmp_path / "link.png"]


def test_compensate_out_equal_to_content_is_refused(probe, tmp_path, content):
    flow = _flow(tmp_path, 0.0, np.s_[:0])
    before = content.read_bytes()
    for out in _same_file_cases(tmp_path, content):
        probe.error(
            probe.projreg("compensate", "--content", content, "--flow", flow, "--out", out),
            "--out",
            "is the input --content",
        )
    assert content.read_bytes() == before


def test_predict_viz_equal_to_projected_is_refused(probe, tmp_path, content):
    captured = tmp_path / "captured.png"
    captured.write_bytes(content.read_bytes())
    before = content.read_bytes()
    for viz in _same_file_cases(tmp_path, content):
        result = probe.projreg(
            "predict", "--projected", content, "--captured", captured, "--out", tmp_path / "f.exr", "--viz", viz, "-q"
        )
        probe.error(result, "--viz", "is the input --projected")
    assert content.read_bytes() == before and not (tmp_path / "f.exr").exists()
    result = probe.projreg(
        "predict", "--projected", content, "--captured", captured, "--out", tmp_path / "f.exr", "--viz", captured, "-q"
    )
    probe.error(result, "--viz", "is the input --captured")
