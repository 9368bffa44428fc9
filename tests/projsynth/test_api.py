"""projsynth's in-memory API: the package root exports it, lazily; bad arrays are one line."""

import subprocess
import sys

import numpy as np
import pytest

import projsynth
from projsynth import ProjsynthError


def test_the_roots_export_the_api_and_importing_them_loads_neither_api_nor_torch():
    code = (
        "import sys, projsynth, projreg\n"
        "print('projsynth.api' in sys.modules, 'projreg.api' in sys.modules, 'torch' in sys.modules)\n"
        "print(projsynth.open_dataset.__module__, projreg.Registrar.__module__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "False False False" and out[1] == "projsynth.api projreg.api"
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        projsynth.nothing  # noqa: B018


def test_bad_arrays_are_refused_with_one_line():
    rgb = np.zeros((64, 96, 3), np.uint8)
    with pytest.raises(ProjsynthError, match=r"^background: expected a uint8 RGB array"):
        projsynth.render_pair(rgb, rgb.astype(np.float32), 0)
    with pytest.raises(ProjsynthError, match="differ in size"):
        projsynth.render_pair(rgb, rgb[:32], 0)
    patterns = projsynth.make_patterns("opencv-graycode", (32, 48))
    photos = patterns.images()
    with pytest.raises(ProjsynthError, match="photos of several sizes"):
        projsynth.decode_photos(patterns, [*photos[:-1], photos[-1][:16]])
    with pytest.raises(ProjsynthError, match="expected uint8 or uint16 images"):
        projsynth.decode_photos(patterns, [p.astype(np.float64) for p in photos])
    exact = projsynth.decode_photos(patterns, photos)  # the projector seen by itself: zero flow
    assert exact.valid.mean() > 0.8 and np.abs(exact.flow[exact.valid]).max() < 0.05


def test_the_device_response_is_fitted_in_memory_as_the_command_fits_files():
    from projsynth.dataset.transforms import builtin_table
    from projsynth.structured.capture import make_rig, shoot

    patterns = projsynth.make_patterns("response", (48, 64), levels=9)
    rig = make_rig(builtin_table(), 0, 2, (48, 64), (48, 64))
    photos = [shoot(rig, img, 2, i) for i, img in enumerate(patterns.images())]  # uint8 RGB, as saved
    curves = projsynth.fit_device_response(patterns, photos)
    assert curves.levels == tuple(patterns.params["levels"]) and curves.projector.shape == (3, 256)
    wide = [(p.astype(np.uint16) * 257) for p in photos]  # 16-bit photos: the same values at full scale
    np.testing.assert_allclose(projsynth.fit_device_response(patterns, wide).projector, curves.projector, atol=1e-6)
    with pytest.raises(ProjsynthError, match="8 photos for 9 grey levels"):
        projsynth.fit_device_response(patterns, photos[1:])
    with pytest.raises(ProjsynthError, match=r"expected uint8 or uint16 RGB \(H, W, 3\) images"):
        projsynth.fit_device_response(patterns, [p[..., 0] for p in photos])
    with pytest.raises(ProjsynthError, match="a dots set"):
        projsynth.fit_device_response(projsynth.make_patterns("dots", (96, 128), grid=(4, 4)), photos)


@pytest.mark.parametrize(
    ("call", "says"),
    [
        (lambda: projsynth.make_patterns("graycode", (0, 80)), r"^--size: expected \(height, width\) in 32..4096"),
        (lambda: projsynth.make_patterns("graycode", (-4, 80)), r"^--size: expected"),
        (lambda: projsynth.make_patterns("dots", (4097, 64)), r"^--size: expected"),
        (lambda: projsynth.make_patterns("opencv-graycode", (100000, 100000)), r"^--size: expected"),
        (lambda: projsynth.make_patterns("graycode", (64, 80), period=0), r"^--period: must be a multiple of 4"),
        (lambda: projsynth.render_pair(*[np.zeros((64, 80, 3), np.uint8)] * 2, "0-3"), r"^transform: expected one"),
        (lambda: projsynth.render_pair(*[np.zeros((64, 80, 3), np.uint8)] * 2, 160), r"^transform: .* 0..159"),
        (lambda: projsynth.render_pair(*[np.zeros((0, 0, 3), np.uint8)] * 2, 0), r"^projected: expected"),
        (lambda: projsynth.render_pair(*[np.zeros((64, 80, 3), np.uint8)] * 2, 0, seed=1.5), r"^seed: expected an int"),
        (lambda: projsynth.make_patterns("graycode", (64, 80), colour=3), r"^colour: not an option .* period, shifts"),
        (lambda: projsynth.make_patterns("graycode", "64x80"), r"^size: expected \(height, width\)"),
        (lambda: projsynth.decode_photos(None, [np.zeros((8, 8), np.uint8)]), r"^patterns: expected a PatternSet"),
        (  # the projector off: refused as `projsynth decode` refuses such photos, not an empty answer
            lambda: projsynth.decode_photos(
                projsynth.make_patterns("graycode", (64, 80)), [np.zeros((48, 64), np.uint8)] * 36
            ),
            r"^photos: only 0.0% of the projector decoded .* barely differ",
        ),
        (lambda: projsynth.fit_device_response("response", []), r"^patterns: expected a PatternSet"),
        (
            lambda: projsynth.decode_photos(projsynth.make_patterns("graycode", (64, 80)), []),
            r"^photos: expected a non",
        ),
        (
            lambda: projsynth.decode_photos(
                projsynth.make_patterns("graycode", (64, 80)), [np.zeros((8, 8, 0), np.uint8)]
            ),
            r"^photos: expected uint8 or uint16",
        ),
    ],
)
def test_sizes_ids_and_photos_are_refused_as_the_command_line_refuses_them(call, says):
    with pytest.raises(ProjsynthError, match=says):
        call()


def test_opencv_photos_with_patterns_and_inverses_swapped_are_refused_as_decode_refuses_them():
    patterns = projsynth.make_patterns("opencv-graycode", (96, 100))
    photos = [np.ascontiguousarray(p) for p in patterns.images()]
    assert projsynth.decode_photos(patterns, photos).valid.mean() > 0.5  # the patterns themselves decode
    for i in range(0, len(photos) - 2, 2):  # every pattern swapped with its inverse (white and black last)
        photos[i], photos[i + 1] = photos[i + 1], photos[i]
    with pytest.raises(ProjsynthError, match=r"^patterns 96x100: .* beyond it; .* of this pattern set and in its"):
        projsynth.decode_photos(patterns, photos)


def test_a_dataset_takes_integers_and_slices_and_refuses_other_keys(tmp_path):
    """A ``Sequence`` takes an index or a slice (a list of samples, as a list's slice); anything else, and a
    path that is not one, gets our message naming it, not a formatting or comparison error from inside."""
    from projsynth.api import open_dataset
    from projsynth.dataset.generate import generate
    from projsynth.dataset.plan import resolve_plan

    root = tmp_path / "d"
    generate(
        resolve_plan(size=(64, 80), seed=0, split="train", pairs=1, transforms="0,26,105", blend="paper"),
        root,
        shard_size=8,
    )
    with open_dataset(root) as data:
        assert len(data) >= 3
        ids = [s["params"]["sample_id"] for s in data[0:2]]
        assert ids == [data[0]["params"]["sample_id"], data[1]["params"]["sample_id"]]
        assert [s["params"]["sample_id"] for s in data[::-1]][0] == data[-1]["params"]["sample_id"]
        assert data[np.int64(1)]["params"]["sample_id"] == ids[1]
        for bad in (1.0, "1", True, None):
            with pytest.raises(TypeError, match="sample index: expected an integer or a slice"):
                data[bad]
        with pytest.raises(IndexError, match="of a dataset of"):
            data[len(data)]
    with pytest.raises(TypeError, match="path: expected a dataset directory"):
        open_dataset(None)
    with pytest.raises(ProjsynthError, match="^path: empty; give a dataset directory$"):
        open_dataset("")  # not the current folder
