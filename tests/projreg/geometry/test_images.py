"""Image operations of the refinement: contrast normalisation, local statistics on shrunk images and the wall's
reflectance divided out."""

import cv2
import numpy as np
from skimage import data

from projreg.geometry.images import LocalStats, divide_albedo, gaussian, normalize_contrast
from projsynth.content.procedural import render_procedural


def test_contrast_normalisation_removes_local_gain_and_offset():
    rng = np.random.default_rng(6)
    gray = cv2.GaussianBlur(rng.integers(0, 256, (80, 100), dtype=np.uint8), (0, 0), 2.0)
    dim = (0.4 * gray + 90).astype(np.uint8)  # a washed-out copy: contrast 0.4, brighter
    a, b = normalize_contrast(gray, 16.0), normalize_contrast(dim, 16.0)
    inner = (slice(20, -20), slice(20, -20))  # away from the border's reflected window
    assert np.abs(a[inner].astype(int) - b[inner].astype(int)).mean() < 3.0
    assert np.abs(a[inner].astype(int) - 128).mean() > 15  # and the texture is still there
    np.testing.assert_array_equal(normalize_contrast(np.full((30, 40), 77, np.uint8), 16.0), 128)
    assert normalize_contrast(gray, 0) is gray  # 0: off


def test_divide_albedo_removes_a_wide_reflectance_pattern_and_keeps_a_misalignment():
    rgb = render_procedural("natural", "urban", (96, 128), np.random.default_rng(4))
    gray0 = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    x = np.arange(128, dtype=np.float32)[None, :]
    wall = np.where(np.sin(2 * np.pi * x / 48) > 0, 0.9, 0.35).astype(np.float32) * np.ones((96, 1), np.float32)
    inner = (slice(16, -16), slice(16, -16))

    def ncc(image):
        return np.corrcoef(image[inner].ravel(), gray0[inner].ravel())[0, 1]

    striped, shifted = gray0 * wall, np.roll(gray0, 3, axis=1) * wall
    assert ncc(striped) < 0.7 and ncc(divide_albedo(gray0, striped, 31)) > 0.95  # the stripes are gone
    assert ncc(divide_albedo(gray0, shifted, 31)) < 0.5  # a 3 px shift is not explained away as reflectance
    moved = np.roll(gray0, 3, axis=1)  # on a plain wall the division leaves a misalignment as it was
    assert abs(ncc(divide_albedo(gray0, moved, 31)) - ncc(moved)) < 0.02


def test_divide_albedo_gives_uint8_images_the_same_values_as_float_ones():
    """uint8 images take table lookups (the refinement's warped captures); float ones the formula."""
    rng = np.random.default_rng(5)
    gray0 = rng.integers(0, 256, (64, 80), dtype=np.uint8)
    warped = cv2.GaussianBlur(rng.integers(0, 256, (64, 80), dtype=np.uint8), (0, 0), 1.5)
    looked_up = divide_albedo(gray0, warped, 15)
    assert looked_up.dtype == np.float32
    np.testing.assert_array_equal(looked_up, divide_albedo(gray0.astype(np.float32), warped.astype(np.float32), 15))
    # the docstring's formula, written out: the median of the coded log ratio is the reflectance
    ratio = np.log(warped.astype(np.float32) + 8.0) - np.log(gray0.astype(np.float32) + 8.0)
    coded = np.clip(np.round(128 + 40 * ratio), 0, 255).astype(np.uint8)
    reflectance = np.exp((cv2.medianBlur(coded, 15).astype(np.float32) - 128) / 40)
    np.testing.assert_array_equal(looked_up, warped / reflectance)


def test_local_statistics_taken_on_the_shrunk_images_agree_with_the_full_size_ones():
    # a photograph (truth nobody here chose) against itself moved by a pixel under noise: the local NCC
    # whose means are taken on the images shrunk twice reads as the full-size one to a few thousandths
    image = cv2.resize(data.camera(), (512, 384)).astype(np.float32)
    moved = np.roll(image, 1, axis=1) + np.random.default_rng(0).normal(0, 5, image.shape).astype(np.float32)
    full, shrunk = LocalStats(image, 7.0).ncc(moved), LocalStats(image, 7.0, 3.5).ncc(moved)
    assert float(np.abs(full - shrunk).mean()) < 0.005 and float(np.abs(full - shrunk).max()) < 0.06  # 0.003, 0.04
    assert not np.array_equal(full, shrunk)  # it was shrunk
    # a window narrower than twice ``shrunk`` is taken at full size, exactly
    np.testing.assert_array_equal(gaussian(image, 3.0, 3.5), gaussian(image, 3.0))
