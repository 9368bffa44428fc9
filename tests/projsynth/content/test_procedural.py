import doctest

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from projsynth import ProjsynthError
from projsynth.content import procedural
from projsynth.content.procedural import KINDS, THEMES, render_procedural

SIZE = (384, 512)
CASES = [(kind, theme) for kind in KINDS for theme in THEMES]


def render(kind: str, theme: str, seed: int, size: tuple[int, int] = SIZE) -> np.ndarray:
    return render_procedural(kind, theme, size, np.random.default_rng(seed))


def gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float64)


def max_autocorrelation(g: np.ndarray, min_shift: int = 8) -> float:
    """Largest normalised autocorrelation over shifts with max(|dy|, |dx|) >= min_shift.

    The image is high-passed first (minus a Gaussian blur, sigma 4 px): smooth content (sky gradients,
    large shapes) correlates with itself at an 8 px shift without being periodic; repetition of the
    fine texture is what makes matching ambiguous. Shifts go up to half the size in each axis (the
    overlap is then >= 1/4 of the image); each shift uses the Pearson-style normalisation over its
    overlap, so a periodic image scores ~1 at its period.
    """
    g = g - cv2.GaussianBlur(g, (0, 0), 4)
    g -= g.mean()
    h, w = g.shape
    spec = np.fft.rfft2(g, (2 * h, 2 * w))
    corr = np.fft.irfft2(spec * np.conj(spec), (2 * h, 2 * w))  # linear (zero-padded) autocorrelation
    sq = np.pad(np.cumsum(np.cumsum(g**2, 0), 1), ((1, 0), (1, 0)))

    def energy(y0, y1, x0, x1):
        return sq[y1, x1] - sq[y0, x1] - sq[y1, x0] + sq[y0, x0]

    dy = np.arange(-(h // 2), h // 2 + 1)[:, None]
    dx = np.arange(-(w // 2), w // 2 + 1)[None, :]
    y0, y1, x0, x1 = np.maximum(0, -dy), np.minimum(h, h - dy), np.maximum(0, -dx), np.minimum(w, w - dx)
    norm = np.sqrt(energy(y0, y1, x0, x1) * energy(y0 + dy, y1 + dy, x0 + dx, x1 + dx))
    r = corr[dy % (2 * h), dx % (2 * w)] / norm
    return float(r[np.maximum(np.abs(dy), np.abs(dx)) >= min_shift].max())


@pytest.mark.parametrize(("kind", "theme"), CASES)
def test_every_tile_is_textured(kind, theme):
    for seed in range(5):
        img = render(kind, theme, seed)
        assert img.shape == (*SIZE, 3) and img.dtype == np.uint8
        tiles = gray(img).reshape(SIZE[0] // 32, 32, SIZE[1] // 32, 32).std(axis=(1, 3))
        assert tiles.min() > 4.0, f"{kind}/{theme} seed {seed}: a 32x32 tile has std {tiles.min():.2f}"


@pytest.mark.parametrize(("kind", "theme"), CASES)
def test_not_periodic(kind, theme):
    for seed in range(2):
        assert max_autocorrelation(gray(render(kind, theme, seed))) < 0.9


def test_periodicity_check_detects_a_tiled_image():
    tile = np.random.default_rng(0).uniform(0, 255, (24, 40))
    periodic = np.tile(tile, (8, 8))[:160, :200]
    assert max_autocorrelation(periodic) > 0.99
    assert max_autocorrelation(np.random.default_rng(1).uniform(0, 255, (160, 200))) < 0.2


@pytest.mark.parametrize(("kind", "theme"), CASES)
def test_deterministic_and_seed_dependent(kind, theme):
    a, b, c = render(kind, theme, 7), render(kind, theme, 7), render(kind, theme, 8)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a.astype(int) - c.astype(int)).mean() > 10


def test_successive_draws_from_one_rng_differ_and_leave_global_state_alone():
    state = np.random.get_state()[1].copy()
    rng = np.random.default_rng(3)
    first, second = (render_procedural("natural", "urban", (64, 80), rng) for _ in range(2))
    assert not np.array_equal(first, second)
    np.testing.assert_array_equal(np.random.get_state()[1], state)


def test_themes_have_their_colours():
    mean = {t: render("natural", t, 0, (96, 128)).reshape(-1, 3).mean(0) for t in THEMES}
    assert mean["forest"][1] > mean["forest"][2]  # green over blue
    assert mean["ocean"][2] > mean["ocean"][0]  # blue over red


@pytest.mark.parametrize("size", [(32, 32), (33, 47), (32, 400), (401, 32), (1080, 1920)])
@pytest.mark.parametrize("kind", KINDS)
def test_sizes(kind, size):
    img = render(kind, THEMES[sum(size) % len(THEMES)], 0, size)
    assert img.shape == (*size, 3) and img.dtype == np.uint8 and img.flags.c_contiguous
    assert gray(img).std() > 10


@settings(max_examples=12, deadline=None)
@given(st.integers(32, 160), st.integers(32, 160), st.sampled_from(CASES), st.integers(0, 2**32))
def test_any_small_size(h, w, case, seed):
    img = render(*case, seed, (h, w))
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    assert gray(img).std() > 5


@pytest.mark.parametrize(
    ("kind", "theme", "size", "match"),
    [("photo", "urban", SIZE, "kind 'photo'"), ("natural", "desert", SIZE, "theme 'desert'"),
     ("natural", "urban", (31, 64), "31x64"), ("generated", "ocean", (64, 0), "64x0")],
)
def test_bad_arguments(kind, theme, size, match):
    with pytest.raises(ProjsynthError, match=match):
        render_procedural(kind, theme, size, np.random.default_rng(0))


def test_docstring_example():
    assert doctest.testmod(procedural).failed == 0
