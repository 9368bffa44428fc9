"""Pattern sets: what each image encodes, checked from the images themselves."""

import json

import numpy as np
import pytest

from projsynth import ProjsynthError
from projsynth.structured.patterns import PATTERNS_FILE, dot_centres, make_set, read_patterns, write_patterns


def test_graycode_columns_decode_from_the_images_alone():
    patterns = make_set("graycode", (64, 96))
    images = dict(zip((n.split("-", 1)[1] for n in patterns.names), patterns.images(), strict=True))
    stripe = patterns.params["stripe"]
    gray = sum(
        (images[f"gray-x{b}"][0] > images[f"gray-x{b}-inv"][0]).astype(int) << b
        for b in range(patterns.params["bits_x"])
    )
    binary = gray.copy()
    for shift in (1, 2, 4, 8):
        binary ^= binary >> shift
    np.testing.assert_array_equal(binary, np.arange(96) // stripe)
    assert np.all(np.count_nonzero(np.diff(gray) != 0) == 96 // stripe - 1)  # one change per stripe edge
    changed = gray[stripe:] ^ gray[:-stripe]
    assert set(np.unique(changed[::stripe])) <= {1 << b for b in range(8)}  # Gray: neighbours differ in one bit


def test_graycode_fringes_carry_the_column_phase():
    patterns = make_set("graycode", (64, 96), period=16, shifts=8)
    images = dict(zip((n.split("-", 1)[1] for n in patterns.names), patterns.images(), strict=True))
    d = 2 * np.pi * np.arange(8) / 8
    row = np.stack([images[f"phase-x{k}"][10].astype(float) for k in range(8)])
    phase = np.arctan2((row * np.sin(d)[:, None]).sum(0), (row * np.cos(d)[:, None]).sum(0))
    expected = np.angle(np.exp(2j * np.pi * np.arange(96) / 16))
    assert np.abs(np.angle(np.exp(1j * (phase - expected)))).max() < 0.02  # 8-bit rounding only


def test_dots_are_discs_centred_on_integer_pixels_with_their_index_in_binary():
    patterns = make_set("dots", (240, 320), grid=(20, 20))
    assert len(patterns.names) == 11 and patterns.params["bits"] == 9
    images = dict(zip((n.split("-", 1)[1] for n in patterns.names), patterns.images(), strict=True))
    r = int(np.ceil(patterns.params["radius"]))
    for i, (x, y) in enumerate(dot_centres(patterns)):
        patch = images["on"][y - r - 1 : y + r + 2, x - r - 1 : x + r + 2].astype(float)
        yy, xx = np.mgrid[-r - 1 : r + 2, -r - 1 : r + 2]
        assert (patch * xx).sum() == 0 and (patch * yy).sum() == 0  # centroid at the centre exactly
        bits = [images[f"bit{b}"][y, x] > 0 for b in range(9)]
        assert sum(int(v) << b for b, v in enumerate(bits)) == i
    assert images["off"].max() == 0


def test_pattern_folder_round_trip_and_edits_refused(tmp_path):
    patterns = make_set("dots", (240, 320), grid=(10, 12))
    files = write_patterns(patterns, tmp_path)
    assert [f.name for f in files[:2]] == ["00-on.png", "01-off.png"] and files[-1].name == PATTERNS_FILE
    assert read_patterns(tmp_path) == patterns
    d = json.loads((tmp_path / PATTERNS_FILE).read_text())
    d["parameters"]["centres_x"][0] += 1
    (tmp_path / PATTERNS_FILE).write_text(json.dumps(d))
    with pytest.raises(ProjsynthError, match="edited"):
        read_patterns(tmp_path)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--kind", "stripes"], "--kind"),
        (["--grid", "50x50"], "--grid"),
        (["--period", "10", "--kind", "graycode"], "--period"),
    ],
)
def test_bad_pattern_options(cli, tmp_path, args, needle):
    base = {"--kind": "dots", "--size": "240x320", "--out": str(tmp_path / "p")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    result = cli.run("patterns", *[x for kv in base.items() for x in kv])
    cli.assert_one_line_error(result, needle)


def test_the_response_set_is_uniform_grey_from_black_to_white_and_reads_back(tmp_path):
    patterns = make_set("response", (32, 48), levels=9)
    images = patterns.images()
    assert patterns.params["levels"] == [0, 32, 64, 96, 128, 159, 191, 223, 255] and len(images) == 9
    for name, img, level in zip(patterns.names, images, patterns.params["levels"], strict=True):
        assert img.shape == (32, 48) and (img == level).all() and name.endswith(f"level{level:03d}")
    assert len(make_set("response", (32, 48)).names) == 17  # the default
    write_patterns(patterns, tmp_path)
    assert read_patterns(tmp_path) == patterns
    d = json.loads((tmp_path / PATTERNS_FILE).read_text())
    d["parameters"]["levels"][4] = 127
    (tmp_path / PATTERNS_FILE).write_text(json.dumps(d))
    with pytest.raises(ProjsynthError, match="edited"):
        read_patterns(tmp_path)
    for bad in (4, 257):
        with pytest.raises(ProjsynthError, match="--levels: must be in 5..256"):
            make_set("response", (32, 48), levels=bad)
    with pytest.raises(ProjsynthError, match="--levels: sets --kind response, not dots"):
        make_set("dots", (240, 320), levels=9)
