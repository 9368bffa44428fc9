"""OpenCV's Gray-code layout (``opencv-graycode``): its convention, the sub-pixel edge decoder against the
integer decode OpenCV does on the same virtual-rig captures, and ``decode --layout opencv`` end to end."""

import importlib.util
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import read_flow_exr
from projsynth.sim.render import ground_truth
from projsynth.structured.capture import capture, make_rig, shoot
from projsynth.structured.decode import decode
from projsynth.structured.edges import decode_edges
from projsynth.structured.patterns import make_set, write_patterns

SIZE = (96, 128)  # projector H x W: 7 column and 7 row bits, 30 images
OPENCV_BLACK_THRESHOLD, OPENCV_WHITE_THRESHOLD = 40, 5  # GrayCodePattern's defaults, 8-bit DN


def opencv_codes(photos8: np.ndarray, bits_x: int, bits_y: int, size: tuple[int, int]):
    """What OpenCV's ``GrayCodePattern::getProjPixel`` gives each camera pixel: integer ``(x, y, ok)``.

    Bit = pattern > inverse, most significant first; a pixel fails when any bit differs by less than
    the white threshold, white - black is not above the black threshold, or the code is out of range.
    """
    ok = photos8[-2] - photos8[-1] > OPENCV_BLACK_THRESHOLD
    coords = []
    for first, n in ((0, bits_x), (2 * bits_x, bits_y)):
        gray = np.zeros(photos8.shape[1:], np.int64)
        for c in range(n):
            a, b = photos8[first + 2 * c], photos8[first + 2 * c + 1]
            gray = (gray << 1) | (a > b)
            ok &= np.abs(a - b) >= OPENCV_WHITE_THRESHOLD
        value, shift = gray.copy(), 1
        while shift < n:
            value ^= value >> shift
            shift <<= 1
        coords.append(value)
    ok &= (coords[0] < size[1]) & (coords[1] < size[0])
    return coords[0], coords[1], ok


def integer_forward(x: np.ndarray, y: np.ndarray, ok: np.ndarray, size: tuple[int, int]):
    """Projector -> camera from integer codes, as OpenCV's decode pools them: each projector pixel at the
    mean position of the camera pixels whose code it is. ``(flow (H, W, 2), valid (H, W))``."""
    h, w = size
    qy, qx = np.mgrid[0 : ok.shape[0], 0 : ok.shape[1]]
    index = (y * w + x)[ok]
    n = np.bincount(index, minlength=h * w).reshape(h, w)
    mean = [np.bincount(index, q[ok], h * w).reshape(h, w) / np.maximum(n, 1) for q in (qx, qy)]
    py, px = np.mgrid[0:h, 0:w]
    return np.stack([mean[0] - px, mean[1] - py], -1), n > 0


def shoot_set(kind: str, tid: int, camera: tuple[int, int] = SIZE, seed: int = 7):
    patterns = make_set(kind, SIZE)
    rig = make_rig(builtin_table(), tid, seed=seed, size=SIZE, camera_size=camera)
    photos = np.stack([shoot(rig, img, seed, i) for i, img in enumerate(patterns.images())])
    return patterns, rig, photos.mean(axis=3, dtype=np.float32)  # [N, Hc, Wc] grey, 0..255


def test_the_layout_is_opencvs():
    """Count, order and polarity as OpenCV's ``generate``: decoding every projector pixel with OpenCV's
    rule gives its own column and row; image 0 is the most significant column bit (right half white)."""
    assert len(make_set("opencv-graycode", (768, 1024)).names) == 2 * (10 + 10) + 2  # OpenCV's default 1024x768
    patterns = make_set("opencv-graycode", SIZE)
    images = np.stack(patterns.images()).astype(np.int64)
    assert len(images) == 2 * (7 + 7) + 2 and patterns.names[-2:] == ("28-white", "29-black")
    x, y, ok = opencv_codes(images, 7, 7, SIZE)
    py, px = np.mgrid[0 : SIZE[0], 0 : SIZE[1]]
    assert ok.all() and (x == px).all() and (y == py).all()
    assert (images[0][:, :64] == 0).all() and (images[0][:, 64:] == 255).all()
    assert (images[1] == 255 - images[0]).all()


# lens/night, sphere/studio, wave/studio, bumps/night: gamma, response, defocus, noise, ambient light
@pytest.mark.parametrize("tid", [26, 85, 125, 146])
def test_subpixel_edges_beat_opencvs_integer_decode(tid):
    patterns, rig, grey = shoot_set("opencv-graycode", tid)
    result = decode(patterns, grey / 255)
    flow, valid, _ = ground_truth(rig.scene)
    both = result.valid & valid
    err = np.hypot(*(result.flow - flow)[both].T)
    x, y, ok = opencv_codes(np.rint(grey).astype(np.int64), 7, 7, SIZE)
    iflow, ivalid = integer_forward(x, y, ok, SIZE)
    ierr = np.hypot(*(iflow - flow)[ivalid & valid].T)
    figures = (tid, np.median(err), np.percentile(err, 95), np.median(ierr), np.percentile(ierr, 95))
    assert np.median(err) <= 0.12 and np.median(err) <= 0.35 * np.median(ierr), figures
    assert np.percentile(err, 95) <= 0.2 and np.percentile(err, 95) <= 0.35 * np.percentile(ierr, 95), figures
    assert both.sum() >= 0.9 * valid.sum(), (tid, both.sum() / valid.sum())
    assert (result.valid & ~valid).sum() <= 0.002 * result.valid.sum()


def test_camera_side_positions_are_subpixel():
    """Per camera pixel, before any pooling: the edge fit's position against OpenCV's integer code."""
    patterns, rig, grey = shoot_set("opencv-graycode", 85)
    stack = {n.split("-", 1)[1]: g / 255 for n, g in zip(patterns.names, grey, strict=True)}
    xp, yp, ok, noise, _ = decode_edges(stack, 7, 7, SIZE)
    xy, lit = rig.view
    truth = np.asarray(xy).T.reshape(*SIZE, 2)
    x, y, iok = opencv_codes(np.rint(grey).astype(np.int64), 7, 7, SIZE)
    lit = np.asarray(lit).reshape(SIZE)
    m = ok & iok & lit  # where both decode
    sub = np.abs(np.stack([xp, yp], -1) - truth)[m]
    integer = np.abs(np.stack([x, y], -1) - truth)[m]
    assert (ok & lit).sum() >= 0.9 * lit.sum() and (iok & lit).sum() < 0.8 * lit.sum()
    assert np.median(sub) <= 0.1 and np.median(sub) <= 0.4 * np.median(integer), (np.median(sub), np.median(integer))
    assert 0 < noise < 0.3


def test_daylight_keeps_what_fixed_thresholds_lose():
    """Cylinder under daylight: white - black is below OpenCV's 40 DN almost everywhere; masks measured
    against the noise keep the lit area, at sub-pixel accuracy."""
    patterns, rig, grey = shoot_set("opencv-graycode", 67)
    result = decode(patterns, grey / 255)
    flow, valid, _ = ground_truth(rig.scene)
    both = result.valid & valid
    _, _, ok = opencv_codes(np.rint(grey).astype(np.int64), 7, 7, SIZE)
    assert ok.mean() < 0.1
    assert both.sum() >= 0.85 * valid.sum()
    assert np.median(np.hypot(*(result.flow - flow)[both].T)) <= 0.1


def analytic_rig():
    """test_decode.py's analytic rig (written apart from projsynth), loaded by path: tests are no package."""
    spec = importlib.util.spec_from_file_location("analytic_rig", Path(__file__).with_name("test_decode.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_analytic_rig_not_projsynths_simulator():
    """test_decode.py's rig (homography + bend, gamma, albedo texture, defocus, pixel-area integration,
    response, noise; camera 1.25x): sub-pixel, most of the in-frame projector, nothing outside the frame."""
    size, camera = (96, 128), (120, 160)
    patterns = make_set("opencv-graycode", size)
    rig = analytic_rig()
    photos = rig.photograph(patterns.images(), camera, 1)  # [N, Hc, Wc] in [0, 1]
    result = decode(patterns, photos)
    truth = rig.true_forward(size)
    py, px = np.mgrid[0 : size[0], 0 : size[1]]
    flow = truth - np.stack([px, py], -1)
    inside = (truth[..., 0] >= 0) & (truth[..., 0] <= camera[1] - 1) & (truth[..., 1] >= 0)
    inside &= truth[..., 1] <= camera[0] - 1
    both = result.valid & inside
    err = np.hypot(*(result.flow - flow)[both].T)
    x, y, ok = opencv_codes(np.rint(photos * 255).astype(np.int64), 7, 7, size)
    iflow, ivalid = integer_forward(x, y, ok, size)
    ierr = np.hypot(*(iflow - flow)[ivalid & inside].T)
    figures = (np.median(err), np.percentile(err, 95), np.median(ierr), np.percentile(ierr, 95))
    assert np.median(err) <= 0.04 and np.percentile(err, 95) <= 0.08, figures
    assert np.median(err) <= 0.2 * np.median(ierr), figures
    assert both.sum() >= 0.93 * inside.sum() and not (result.valid & ~inside).any()


@pytest.fixture(scope="module")
def opencv_run(tmp_path_factory) -> Path:
    """patterns -> virtual capture (one picture) -> the photos renamed as OpenCV's capture sample names them."""
    root = tmp_path_factory.mktemp("opencv")
    picture = np.random.default_rng(0).integers(0, 256, (96, 128, 3), np.uint8)
    cv2.imwrite(str(root / "picture.png"), cv2.GaussianBlur(picture, (0, 0), 2))
    patterns = make_set("opencv-graycode", SIZE)
    write_patterns(patterns, root / "pat")
    capture(patterns, root / "cap", table=builtin_table(), transform=85, contents=[root / "picture.png"])
    (root / "photos").mkdir()
    for i, name in enumerate(patterns.names):  # im1..im30: the name order must be natural
        shutil.copy(root / "cap" / f"{name}.png", root / "photos" / f"pattern_cam1_im{i + 1}.png")
    return root


def test_decode_layout_opencv_end_to_end(opencv_run, cli, tmp_path):
    out = tmp_path / "real"
    content = opencv_run / "cap" / "content"
    result = cli.run(
        "decode", "--layout", "opencv", "--projector", "96x128", "--captures", opencv_run / "photos", "--out", out,
        "--pair", content / "picture-projected.png", content / "picture.png",
    )  # fmt: skip
    assert result.exit_code == 0, result.stderr
    flow, valid, _ = read_flow_exr(out / "correspondence.exr")
    truth, truth_valid, _ = read_flow_exr(opencv_run / "cap" / "truth.exr")
    both = valid & truth_valid
    assert both.sum() >= 0.9 * truth_valid.sum()
    assert np.median(np.hypot(*(flow - truth)[both].T)) <= 0.12
    record = json.loads((out / "decode.json").read_text())
    assert record["layout"] == "opencv" and record["kind"] == "opencv-graycode"
    assert record["photos"][:2] == ["pattern_cam1_im1.png", "pattern_cam1_im2.png"]
    assert record["photos"][-1] == "pattern_cam1_im30.png"
    assert cli.run("verify", out).exit_code == 0
    assert cli.manifest(out)["captured"]["patterns_kind"] == "opencv-graycode"
    same = cli.run(
        "decode", "--patterns", opencv_run / "pat", "--captures", opencv_run / "cap", "--out", tmp_path / "b"
    )
    assert same.exit_code == 0, same.stderr
    assert (read_flow_exr(tmp_path / "b" / "correspondence.exr")[0] == flow).all()


@pytest.mark.parametrize("damage", ["count", "size", "unreadable", "not-hxw", "swapped", "no-projector"])
def test_bad_opencv_input_is_one_clear_error(opencv_run, cli, tmp_path, damage):
    photos = tmp_path / "photos"
    shutil.copytree(opencv_run / "photos", photos)
    projector, needle = "96x128", ""
    if damage == "count":
        (photos / "pattern_cam1_im30.png").unlink()
        needle = "29 images"
    elif damage == "size":
        img = cv2.imread(str(photos / "pattern_cam1_im7.png"))
        cv2.imwrite(str(photos / "pattern_cam1_im7.png"), img[:-2])
        needle = "pattern_cam1_im7.png"
    elif damage == "unreadable":
        (photos / "pattern_cam1_im3.png").write_bytes(b"not a png")
        needle = "pattern_cam1_im3.png"
    elif damage == "not-hxw":
        projector, needle = "96by128", "--projector"
    elif damage == "swapped":  # 7 + 7 bits either way: the codes, not the count, show it
        projector, needle = "128x96", "--projector 128x96"
    args = ["decode", "--layout", "opencv", "--captures", photos, "--out", tmp_path / "o"]
    if damage == "no-projector":
        needle = "--projector"
    else:
        args += ["--projector", projector]
    cli.assert_one_line_error(cli.run(*args), needle)
    assert not (tmp_path / "o").exists()
