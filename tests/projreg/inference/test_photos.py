"""The surface divided out of a capture, on a scene written here: a textured wall in ambient light, a
projector whose picture lands shifted on it, a camera with gamma 2.2."""

import numpy as np
import pytest

from projreg import ProjregError
from projreg.inference.photos import MARGIN, normalise_capture
from projsynth.structured.response import Response

H, W, SHIFT = 40, 56, (5, 3)  # the camera sees projector pixel (x, y) at (x + 5, y + 3)
AMBIENT, POWER = 0.25, 0.7


def encode(lin):
    return np.clip(np.rint(255 * np.clip(lin, 0, 1) ** (1 / 2.2)), 0, 255).astype(np.uint8)


def decode(img):
    return (img.astype(np.float64) / 255) ** 2.2


def scene():
    """``photo(projected)``: the camera's photo of a projector image (the wall's albedo times ambient plus
    projector light, in linear light); and the projector's light warped into the camera, None where it
    does not reach (the left and top strips the shift leaves dark)."""
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.35, 1.0, (H, W, 3))  # a textured, coloured wall
    dx, dy = SHIFT

    def warped(projected):
        out = np.zeros((H, W, 3))
        out[dy:, dx:] = decode(projected)[: H - dy, : W - dx]
        return out

    def photo(projected):
        return encode(albedo * (AMBIENT + POWER * warped(projected)))

    return photo, warped


def test_white_and_black_give_the_projected_picture_back_where_the_projector_reaches():
    photo, warped = scene()
    rng = np.random.default_rng(1)
    projected = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    white, black = photo(np.full((H, W, 3), 255, np.uint8)), photo(np.zeros((H, W, 3), np.uint8))
    out = normalise_capture(photo(projected), white, black)
    dx, dy = SHIFT
    seen = projected[: H - dy, : W - dx]
    # what is left is the photos' 8-bit rounding, divided by a white above black by >= 0.35 * 0.7 in linear
    # light: in linear light a few thousandths; in grey levels a few, more near black (the inverse gamma is steep)
    error = np.abs(decode(out[dy:, dx:]) - decode(seen))
    assert error.max() < 0.02 and error.mean() < 0.004
    bright = seen >= 64
    assert np.abs(out[dy:, dx:].astype(int) - seen)[bright].max() <= 6
    assert not out[:dy].any() and not out[:, :dx].any()  # white == black there: the projector does not reach


def test_one_pixel_by_hand():
    one = lambda v: np.full((1, 1, 3), v, np.uint8)  # noqa: E731
    assert normalise_capture(one(128), one(200), one(50), gamma=1.0)[0, 0, 0] == 133  # 255 * 78 / 150 = 132.6
    # gamma 2.2: linear 0.21952, 0.02776, 0.58597; (0.21952 - 0.02776) / (0.58597 - 0.02776) = 0.34353,
    # ^(1 / 2.2) = 0.61528, x 255 = 156.9
    assert normalise_capture(one(128), one(200), one(50))[0, 0, 0] == 157
    # white alone: captured / white, the ambient light stays in; the gamma cancels: 255 * 128 / 200 = 163.2
    assert normalise_capture(one(128), one(200))[0, 0, 0] == 163
    # brighter than white (a saturated white photo): clipped; darker than black: 0
    assert normalise_capture(one(255), one(255), one(10))[0, 0, 0] == 255
    assert normalise_capture(one(250), one(200), one(10))[0, 0, 0] == 255
    assert normalise_capture(one(5), one(200), one(10))[0, 0, 0] == 0


def test_per_channel_the_margin_decides_where_the_projector_reaches():
    captured = np.array([[[100, 100, 100]]], np.uint8)
    black = np.array([[[60, 60, 60]]], np.uint8)
    white = black + np.array([MARGIN, MARGIN - 1, 120], np.uint8)  # red just reached, green not, blue well
    out = normalise_capture(np.repeat(captured, 2, 1), np.repeat(white, 2, 1), np.repeat(black, 2, 1))
    assert out[0, 0, 0] == 255 and out[0, 0, 1] == 0 and 0 < out[0, 0, 2] < 255


def test_white_alone_divides_the_colour_out_not_the_ambient_light():
    photo, warped = scene()
    projected = np.full((H, W, 3), 128, np.uint8)
    out = normalise_capture(photo(projected), photo(np.full((H, W, 3), 255, np.uint8)))
    dx, dy = SHIFT
    expected = encode((AMBIENT + POWER * decode(projected)) / (AMBIENT + POWER))  # the albedo cancels
    assert np.abs(out[dy:, dx:].astype(int) - expected[dy:, dx:]).max() <= 3
    assert (out[:dy] == 255).all()  # unlit, the white photo is the captured one: it cannot tell a shadow


def test_photos_that_cannot_be_this_rigs_are_refused_naming_the_option():
    photo, _ = scene()
    white, black = photo(np.full((H, W, 3), 255, np.uint8)), photo(np.zeros((H, W, 3), np.uint8))
    captured = photo(np.full((H, W, 3), 90, np.uint8))
    with pytest.raises(ProjregError, match=r"^--white is 28x20 px but the captured image is 56x40"):
        normalise_capture(captured, white[::2, ::2], black)
    with pytest.raises(ProjregError, match=r"^--white is 56x40 px but --black is 55x40"):
        normalise_capture(captured, white, black[:, 1:])
    with pytest.raises(ProjregError, match=r"^--white is darker than --black on 84% of the frame: are the two"):
        normalise_capture(captured, black, white)
    with pytest.raises(ProjregError, match=r"^--white is nowhere brighter than --black by 4 grey levels"):
        normalise_capture(captured, black, black)
    with pytest.raises(ProjregError, match=r"^--white is nowhere brighter than black by 4 grey levels"):
        normalise_capture(captured, np.full_like(white, MARGIN - 1))


def test_with_the_devices_measured_response_the_projected_codes_come_back():
    """A camera of exponent 1.6 and a projector of gamma 2.6 (not 2.2): linearised by the measured curves,
    the ratio read back through the projector's inverse curve is the code value it was sent."""
    rng = np.random.default_rng(3)
    albedo = rng.uniform(0.35, 1.0, (H, W, 3))
    projected = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    curve = (np.arange(256, dtype=np.float64) / 255) ** 2.6

    def photo(codes):  # the camera's photo of projector codes, no shift: ambient + projector light, exponent 1.6
        light = albedo * (AMBIENT + POWER * curve[codes])
        return np.clip(np.rint(255 * np.clip(light, 0, 1) ** (1 / 1.6)), 0, 255).astype(np.uint8)

    white, black = photo(np.full_like(projected, 255)), photo(np.zeros_like(projected))
    response = Response(1.6, np.tile(curve, (3, 1)).astype(np.float32))
    measured = normalise_capture(photo(projected), white, black, response)
    assumed = normalise_capture(photo(projected), white, black)  # gamma 2.2 for both devices
    mid = (projected > 40) & (projected < 215)  # away from the 8-bit camera's coarse steps at either end
    err_measured = np.abs(measured.astype(int) - projected)[mid]
    err_assumed = np.abs(assumed.astype(int) - projected)[mid]
    assert np.median(err_measured) <= 1 and err_measured.mean() < 2.0, err_measured.mean()
    assert err_assumed.mean() > 3 * err_measured.mean(), (err_assumed.mean(), err_measured.mean())
    same = normalise_capture(photo(projected), white, black, Response.from_gamma(2.2))
    assert np.abs(same.astype(int) - assumed).max() <= 1  # the assumed gamma as a response: the gamma path
