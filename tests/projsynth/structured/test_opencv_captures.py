"""Third-party captures of OpenCV's Gray-code layout decode at least as completely as OpenCV's own decoder, at
its accuracy or better: noise-free photos (black exactly 0), photos whose white clips at 255 on a sixth of
the lit pixels, and perfect captures (the patterns themselves as the photos).

The scenes are test_decode.py's analytic rig (a homography and a smooth bend, camera 1.25x the projector),
photographed here without noise. OpenCV's figures were measured on these very photos with its own decoder
(``bench/opencv_graycode_ref.py``, opencv-contrib-python-headless 5.1.0; docs/real-rig.md, section 8).
Coverage is the share of the projector pixels whose true camera position lies in the camera frame that get
a correspondence: ours, valid in the correspondence; OpenCV's, hit by at least one camera pixel its decoder
keeps. Errors are camera px against the analytic truth; OpenCV's at a projector pixel is the mean position
of the camera pixels that decode to it (how its ``decode`` pools them).
"""

import importlib.util
import json
import subprocess
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from projsynth.flow.formats import read_flow_exr
from projsynth.structured.decode import decode
from projsynth.structured.edges import MIN_DIFF_NOISE
from projsynth.structured.patterns import make_set

CAMERAS = {(96, 128): (120, 160), (240, 320): (300, 400), (480, 640): (600, 800)}  # 1.25x, as test_decode.py
SUPERSAMPLING = 4  # rays per camera pixel and axis: a camera pixel integrates its area
DEFOCUS_PX = 1.0  # Gaussian sigma of the camera's defocus, camera px
RESPONSE = 1 / 2.2  # the camera's value = light ** RESPONSE: an ordinary 8-bit photo
CLIPPED_SHARE = 1 / 6  # of the lit camera pixels whose white clips at 255 in the clipped photos
# a smooth albedo texture in this range, mostly dark with a few bright patches (u^3, u uniform): the clipped
# photos clip those patches deeply, as a white object in a darker scene
ALBEDO = (0.15, 1.0)
HEADROOM = 0.95  # the brightest white of the noise-free photos, of full scale: nothing clips
# OpenCV's figures on these photos (bench/opencv_graycode_ref.py --sizes 96x128,240x320 --cases noise-free,clipped,
# measured 2026-12-05; docs/real-rig.md, section 8), each rounded in OpenCV's favour: its coverage up (ours must
# reach it), its mean and largest error over the projector pixels it decodes down (ours must stay under
# MAX_MEAN_SHARE of the mean, and under the largest, everywhere we decode)
OPENCV_COVERAGE = {
    ("noise-free", (96, 128)): 0.944,  # 94.34 %
    ("clipped", (96, 128)): 0.964,  # 96.38 %
    ("noise-free", (240, 320)): 0.875,  # 87.40 %
    ("clipped", (240, 320)): 0.906,  # 90.59 %
}
OPENCV_ERROR = {  # (mean, max), camera px
    ("noise-free", (96, 128)): (0.36, 1.5),  # 0.369, 1.512
    ("clipped", (96, 128)): (0.36, 1.7),  # 0.365, 1.794
    ("noise-free", (240, 320)): (0.36, 1.8),  # 0.365, 1.884
    ("clipped", (240, 320)): (0.36, 1.7),  # 0.367, 1.711
}
MAX_MEAN_SHARE = 1 / 3  # OpenCV's mean is its integer codes' rounding (about 0.35 px): ours must be well under


def analytic_rig():
    """test_decode.py's analytic rig (written apart from projsynth), loaded by path: tests are no package."""
    spec = importlib.util.spec_from_file_location("analytic_rig", Path(__file__).with_name("test_decode.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def noise_free_photos(
    patterns: list[np.ndarray], camera: tuple[int, int], clipped: bool, response: float = RESPONSE
) -> np.ndarray:
    """Photos ``(N, Hc, Wc)`` uint8 of uint8 projector ``patterns`` through the analytic rig, without noise.

    Each projector pixel is a square of constant light; the surface an albedo texture; the camera
    defocuses, integrates its pixel's area, applies ``response`` and quantises; no ambient light, so black
    is exactly 0. The gain puts the brightest white at ``HEADROOM``, or, ``clipped``, clips the white of the
    brightest ``CLIPPED_SHARE`` of the lit pixels at 255.
    """
    rig = analytic_rig()
    hc, wc, s = *camera, SUPERSAMPLING
    ys, xs = np.mgrid[0 : hc * s, 0 : wc * s].astype(np.float64)
    px, py = rig.proj_from_cam((xs + 0.5) / s - 0.5, (ys + 0.5) / s - 0.5)
    h, w = patterns[0].shape
    ix, iy = np.floor(px + 0.5).astype(np.int64), np.floor(py + 0.5).astype(np.int64)
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    ix, iy = ix.clip(0, w - 1), iy.clip(0, h - 1)
    coarse = ALBEDO[0] + (ALBEDO[1] - ALBEDO[0]) * np.random.default_rng(5).uniform(0, 1, (9, 12)) ** 3
    albedo = cv2.resize(coarse.astype(np.float32), (wc * s, hc * s), interpolation=cv2.INTER_CUBIC).clip(*ALBEDO)

    def light(pattern: np.ndarray) -> np.ndarray:  # [Hc, Wc] linear, before the gain
        seen = albedo * (pattern[iy, ix].astype(np.float32) / 255) * inside
        return cv2.resize(cv2.GaussianBlur(seen, (0, 0), DEFOCUS_PX * s), (wc, hc), interpolation=cv2.INTER_AREA)

    white = light(np.full((h, w), 255, np.uint8))
    lit = white > 0.01 * white.max()
    gain = 1 / np.quantile(white[lit], 1 - CLIPPED_SHARE) if clipped else HEADROOM ** (1 / response) / white.max()
    return np.stack([np.clip(np.rint(255 * (gain * light(p)) ** response), 0, 255).astype(np.uint8) for p in patterns])


def true_forward(size: tuple[int, int]) -> np.ndarray:
    """``(H, W, 2)``: the camera position of every projector pixel."""
    return analytic_rig().true_forward(size)


def in_frame(truth: np.ndarray, camera: tuple[int, int]) -> np.ndarray:
    """Projector pixels whose true camera position lies in the camera frame."""
    hc, wc = camera
    return (truth[..., 0] >= 0) & (truth[..., 0] <= wc - 1) & (truth[..., 1] >= 0) & (truth[..., 1] <= hc - 1)


def decode_quietly(patterns, photos8: np.ndarray):
    """:func:`decode` of uint8 photos, any warning an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return decode(patterns, photos8.astype(np.float32) / 255)


def errors(result, truth: np.ndarray) -> np.ndarray:
    """Camera px between the decoded and the true camera position of every valid projector pixel."""
    ys, xs = np.mgrid[0 : truth.shape[0], 0 : truth.shape[1]]
    return np.hypot(*(result.flow + np.stack([xs, ys], -1) - truth)[result.valid].T)


@pytest.mark.parametrize("size", [(96, 128), (240, 320)], ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("kind", ["noise-free", "clipped"])
def test_noise_free_and_clipped_photos_decode_as_completely_as_opencv(kind, size):
    patterns = make_set("opencv-graycode", size)
    camera = CAMERAS[size]
    photos = noise_free_photos(patterns.images(), camera, clipped=kind == "clipped")
    lit = photos[-2] > 0
    if kind == "clipped":
        assert (photos[-2][lit] == 255).mean() >= 0.9 * CLIPPED_SHARE
    else:
        assert photos[-2].max() < 255 and (photos[-1] == 0).all()
    result = decode_quietly(patterns, photos)
    truth = true_forward(size)
    inside = in_frame(truth, camera)
    coverage = (result.valid & inside).sum() / inside.sum()
    err = errors(result, truth)
    opencv_mean, opencv_max = OPENCV_ERROR[kind, size]
    figures = (coverage, err.mean(), np.percentile(err, 99), err.max())
    assert coverage >= OPENCV_COVERAGE[kind, size], figures
    assert err.mean() <= MAX_MEAN_SHARE * opencv_mean and err.max() <= opencv_max, figures
    assert not (result.valid & ~inside).any()
    # noise-free: the noise of pattern - inverse is the photos' 8-bit quantisation
    assert result.stats["diff_noise_dn"] == pytest.approx(255 * MIN_DIFF_NOISE, rel=1e-3)


@pytest.mark.parametrize("size", [(96, 128), (240, 320), (100, 150)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_a_perfect_capture_decodes_every_projector_pixel_exactly(size):
    """The patterns themselves as the photos (camera = projector grid): OpenCV's decoder gives every pixel its
    own column and row; so does ours, including the frame's first and last columns and rows."""
    patterns = make_set("opencv-graycode", size)
    result = decode_quietly(patterns, np.stack(patterns.images()))
    assert result.valid.all() and np.abs(result.flow).max() <= 1e-6
    assert result.stats["diff_noise_dn"] == pytest.approx(255 * MIN_DIFF_NOISE, rel=1e-3)


def test_a_linear_camera_warns_of_nothing():
    """A linear camera (raw): ``pattern + inverse - white - black`` is float rounding on most pixels, which once
    made the noise's box average dip below 0 (``invalid value encountered in sqrt``)."""
    size = (96, 128)
    patterns = make_set("opencv-graycode", size)
    for clipped in (False, True):
        result = decode_quietly(patterns, noise_free_photos(patterns.images(), CAMERAS[size], clipped, response=1.0))
        assert result.stats["diff_noise_dn"] == pytest.approx(255 * MIN_DIFF_NOISE, rel=1e-3)


def test_decode_layout_opencv_prints_nothing_but_its_summary(cli, tmp_path):
    """``projsynth decode --layout opencv`` (a process of its own, so a warning would reach its stderr) on
    clipped photos named as OpenCV's capture sample names them: its one summary line and nothing else, and
    ``decode.json`` with the photos' noise."""
    size = (96, 128)
    patterns = make_set("opencv-graycode", size)
    photos = noise_free_photos(patterns.images(), CAMERAS[size], clipped=True)
    (tmp_path / "cam1").mkdir()
    for i, photo in enumerate(photos):
        cv2.imwrite(str(tmp_path / "cam1" / f"pattern_cam1_im{i + 1}.png"), photo)
    args = [
        "decode",
        "--layout",
        "opencv",
        "--projector",
        "96x128",
        "--captures",
        tmp_path / "cam1",
        "--out",
        tmp_path / "o",
    ]
    result = subprocess.run([cli.exe(), *map(str, args)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    (line,) = cli.visible_lines(result.stderr)  # its summary, nothing else
    assert line.startswith(f"{tmp_path / 'o'}: ") and line.endswith("decoded into correspondence.exr"), line
    record = json.loads((tmp_path / "o" / "decode.json").read_text())
    assert record["diff_noise_dn"] == pytest.approx(255 * MIN_DIFF_NOISE, rel=1e-3)
    flow, valid, _ = read_flow_exr(tmp_path / "o" / "correspondence.exr")
    inside = in_frame(true_forward(size), CAMERAS[size])
    assert (valid & inside).sum() / inside.sum() >= OPENCV_COVERAGE["clipped", size]
