import doctest
import io
import struct

import numpy as np
import OpenEXR
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from projsynth import ProjsynthError
from projsynth.flow import formats as flowio
from projsynth.flow.formats import (
    decode_flow_exr,
    decode_flow_file,
    encode_flow_exr,
    read_flo,
    read_flow_exr,
    read_flow_file,
    write_flo,
    write_flow_exr,
)
from projsynth.flow.pictures import COLOR_WHEEL, flow_to_color

SPECIALS = np.array(
    [0.0, -0.0, 1e-45, -1e-45, 1.1754944e-38, 1e-30, -1e-7, 599.99997, -600.0, 600.0, 0.5, -0.25],
    np.float32,
)


def random_flow(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    flow = rng.uniform(-600, 600, (h, w, 2)).astype(np.float32)
    k = min(SPECIALS.size, h * w * 2)
    flow.reshape(-1)[rng.choice(h * w * 2, k, replace=False)] = SPECIALS[:k]
    return flow, rng.random((h, w)) < 0.7


def assert_bits_equal(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


# --- OpenEXR -------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(7, 13), (1, 1), (13, 7), (40, 33)])
def test_exr_round_trip_is_bit_exact(shape):
    flow, valid = random_flow(np.random.default_rng(0), *shape)
    flow2, valid2, header = decode_flow_exr(encode_flow_exr(flow, valid, "pair00003-nat-t017"))
    assert_bits_equal(flow2, flow)
    assert flow2.flags.c_contiguous
    assert valid2.dtype == np.bool_
    np.testing.assert_array_equal(valid2, valid)
    assert header["units"] == "px"
    assert header["direction"] == "projected->captured"
    assert header["sample_id"] == "pair00003-nat-t017"


def test_exr_negative_zero_survives():
    flow = np.full((2, 3, 2), -0.0, np.float32)
    out, _, _ = decode_flow_exr(encode_flow_exr(flow, np.ones((2, 3), bool), "z"))
    assert np.signbit(out).all()


def test_exr_stores_the_documented_channels():
    flow, valid = random_flow(np.random.default_rng(1), 5, 4)
    exr = OpenEXR.File(io.BytesIO(encode_flow_exr(flow, valid, "s")), separate_channels=True)
    ch = exr.channels()
    assert set(ch) == {"forward.u", "forward.v", "valid"}
    assert all(c.pixels.dtype == np.float32 for c in ch.values())
    np.testing.assert_array_equal(ch["forward.u"].pixels, flow[..., 0])
    np.testing.assert_array_equal(ch["forward.v"].pixels, flow[..., 1])
    assert set(np.unique(ch["valid"].pixels)) <= {0.0, 1.0}
    assert exr.header()["compression"] == OpenEXR.ZIP_COMPRESSION


def test_exr_non_contiguous_inputs_round_trip():
    rng = np.random.default_rng(2)
    base, mask = random_flow(rng, 13, 9)
    views = [
        (base.transpose(1, 0, 2), mask.T),  # transposed
        (base[::2, ::3], mask[::2, ::3]),  # strided
        (np.ascontiguousarray(base[..., ::-1])[..., ::-1], mask[::-1]),  # negative strides
    ]
    for flow, valid in views:
        assert not flow.flags.c_contiguous
        out, valid2, _ = decode_flow_exr(encode_flow_exr(flow, valid, "nc"))
        assert_bits_equal(out, np.ascontiguousarray(flow))
        np.testing.assert_array_equal(valid2, valid)


def test_exr_float64_input_is_stored_as_float32():
    flow, valid = random_flow(np.random.default_rng(3), 4, 5)
    out, _, _ = decode_flow_exr(encode_flow_exr(flow.astype(np.float64), valid, "f64"))
    assert_bits_equal(out, flow)


@pytest.mark.parametrize("compression", ["zip", "pxr24"])
def test_exr_encoding_is_deterministic(compression):
    flow, valid = random_flow(np.random.default_rng(4), 96, 128)
    a = encode_flow_exr(flow, valid, "det", compression)
    b = encode_flow_exr(flow.copy(), valid.copy(), "det", compression)
    assert a == b
    assert encode_flow_exr(flow, valid, "det2", compression) != a


def test_exr_pxr24_error_is_below_a_hundredth_of_a_pixel():
    rng = np.random.default_rng(5)
    flow = rng.uniform(-500, 500, (256, 256, 2)).astype(np.float32)
    flow[0, :6, 0] = [500.0, -500.0, 499.99997, 256.0, 255.99998, 0.0]
    valid = rng.random((256, 256)) < 0.5
    out, valid2, _ = decode_flow_exr(encode_flow_exr(flow, valid, "lossy", "pxr24"))
    err = np.abs(out.astype(np.float64) - flow)
    assert 0 < err.max() <= 2.0**-8 < 0.01  # lossy, within half a 24-bit ulp below 512
    np.testing.assert_array_equal(valid2, valid)


@pytest.mark.parametrize(
    "flow, valid, sample_id, compression",
    [
        (np.zeros((4, 5, 2), np.float32), np.ones((4, 5), bool), "s", "zstd"),
        (np.zeros((4, 5, 3), np.float32), np.ones((4, 5), bool), "s", "zip"),
        (np.zeros((4, 5), np.float32), np.ones((4, 5), bool), "s", "zip"),
        (np.zeros((0, 5, 2), np.float32), np.ones((0, 5), bool), "s", "zip"),
        (np.zeros((4, 5, 2), np.int32), np.ones((4, 5), bool), "s", "zip"),
        (np.zeros((4, 5, 2), np.float32), np.ones((5, 4), bool), "s", "zip"),
        (np.zeros((4, 5, 2), np.float32), np.ones((4, 5), np.uint8), "s", "zip"),
        (np.zeros((4, 5, 2), np.float32), np.ones((4, 5), bool), 7, "zip"),
    ],
)
def test_exr_bad_input_raises(flow, valid, sample_id, compression):
    with pytest.raises(ProjsynthError):
        encode_flow_exr(flow, valid, sample_id, compression)


def test_exr_corrupt_bytes_raise():
    flow, valid = random_flow(np.random.default_rng(6), 32, 24)
    data = encode_flow_exr(flow, valid, "c")
    rng = np.random.default_rng(7)
    bad = [b"", b"\x00", rng.bytes(4000), data[:4] + rng.bytes(400), "not bytes"]
    bad += [data[:n] for n in (3, 40, len(data) // 3, len(data) // 2, len(data) - 1)]
    for blob in bad:
        with pytest.raises(ProjsynthError, match="not a valid OpenEXR flow file"):
            decode_flow_exr(blob)


def test_exr_missing_channel_raises():
    buf = io.BytesIO()
    z = np.zeros((3, 4), np.float32)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"forward.u": z, "forward.v": z}).write(buf)
    with pytest.raises(ProjsynthError, match="missing channel.*valid"):
        decode_flow_exr(buf.getvalue())


def test_exr_file_round_trip_is_atomic_and_names_the_path(tmp_path):
    flow, valid = random_flow(np.random.default_rng(8), 11, 6)
    path = tmp_path / "f.exr"
    path.write_bytes(b"old")
    write_flow_exr(path, flow, valid, "disk")
    assert [p.name for p in tmp_path.iterdir()] == ["f.exr"]  # temp file renamed, none left over
    assert path.read_bytes() == encode_flow_exr(flow, valid, "disk")
    flow2, valid2, header = read_flow_exr(str(path))
    assert_bits_equal(flow2, flow)
    np.testing.assert_array_equal(valid2, valid)
    assert header["sample_id"] == "disk"
    path.write_bytes(b"garbage")
    with pytest.raises(ProjsynthError, match="f.exr.*not a valid OpenEXR flow file"):
        read_flow_exr(path)
    with pytest.raises(ProjsynthError, match="missing.exr"):
        read_flow_exr(tmp_path / "missing.exr")
    with pytest.raises(ProjsynthError, match="no_dir"):
        write_flow_exr(tmp_path / "no_dir" / "f.exr", flow, valid, "x")


flow_shapes = st.tuples(st.integers(1, 9), st.integers(1, 9), st.just(2))


@settings(max_examples=60, deadline=None)
@given(
    flow=arrays(np.float32, flow_shapes, elements=st.floats(width=32)),
    data=st.data(),
    sample_id=st.text(max_size=40),
    compression=st.sampled_from(["zip", "pxr24"]),
)
def test_exr_round_trip_property(flow, data, sample_id, compression):
    valid = data.draw(arrays(np.bool_, flow.shape[:2]))
    out, valid2, header = decode_flow_exr(encode_flow_exr(flow, valid, sample_id, compression))
    np.testing.assert_array_equal(valid2, valid)
    assert header["sample_id"] == sample_id
    if compression == "zip":
        assert_bits_equal(out, flow)  # any float32 bit pattern, NaN and inf included
    else:
        finite = np.isfinite(flow) & (np.abs(flow) < 2.0**127)
        bound = np.abs(flow[finite]) * 2.0**-16 + 2.0**-141  # relative, or 2**7 ulp for subnormals
        assert np.all(np.abs(out[finite].astype(np.float64) - flow[finite]) <= bound)


# --- Middlebury .flo -----------------------------------------------------------------------------


def test_flo_header_bytes_are_hand_computed(tmp_path):
    flow = np.zeros((7, 13, 2), np.float32)
    flow[0, 0] = (1.5, -2.0)
    path = tmp_path / "a.flo"
    write_flo(path, flow)
    data = path.read_bytes()
    assert struct.pack("<f", 202021.25) == b"PIEH"
    assert data[:4] == b"PIEH"
    assert data[4:8] == b"\x0d\x00\x00\x00"  # width 13, little-endian int32
    assert data[8:12] == b"\x07\x00\x00\x00"  # height 7
    assert data[12:20] == b"\x00\x00\xc0\x3f" + b"\x00\x00\x00\xc0"  # 1.5, -2.0 as little-endian float32
    assert len(data) == 12 + 7 * 13 * 2 * 4


@settings(max_examples=40, deadline=None)
@given(flow=arrays(np.float32, flow_shapes, elements=st.floats(width=32, allow_nan=False)))
def test_flo_round_trip_property(tmp_path_factory, flow):
    path = tmp_path_factory.mktemp("flo") / "p.flo"
    write_flo(path, flow)
    assert_bits_equal(read_flo(path), flow)


def test_flo_round_trip_non_contiguous_and_invalid(tmp_path):
    flow, valid = random_flow(np.random.default_rng(9), 9, 14)
    path = tmp_path / "b.flo"
    write_flo(path, flow.transpose(1, 0, 2), valid.T)
    out = read_flo(path)
    assert out.shape == (14, 9, 2) and out.flags.c_contiguous and out.flags.writeable
    assert_bits_equal(out[valid.T], flow.transpose(1, 0, 2)[valid.T])
    assert np.all(out[~valid.T] > 1e9)
    assert [p.name for p in tmp_path.iterdir()] == ["b.flo"]


def test_flo_errors_name_the_file(tmp_path):
    bad_magic = tmp_path / "magic.flo"
    bad_magic.write_bytes(struct.pack("<fii", 1.0, 1, 1) + bytes(8))
    short = tmp_path / "short.flo"
    short.write_bytes(struct.pack("<fii", 202021.25, 4, 3) + bytes(8 * 12 - 1))
    negative = tmp_path / "neg.flo"
    negative.write_bytes(struct.pack("<fii", 202021.25, -1, 3))
    for path in (bad_magic, short, negative, tmp_path / "empty.flo", tmp_path / "missing.flo"):
        if path.stem == "empty":
            path.write_bytes(b"")
        with pytest.raises(ProjsynthError, match=path.name):
            read_flo(path)
    with pytest.raises(ProjsynthError, match="x.flo"):
        write_flo(tmp_path / "x.flo", np.zeros((3, 4, 2), np.float32), np.ones((4, 3), bool))


# --- colour wheel --------------------------------------------------------------------------------


def test_color_wheel_matches_its_definition():
    assert COLOR_WHEEL.shape == (55, 3)
    # segment starts: RY 0, YG 15, GC 21, CB 25, BM 36, MR 49
    expected = {
        0: (255, 0, 0),
        14: (255, 238, 0),  # floor(255 * 14 / 15) = 238
        15: (255, 255, 0),
        16: (213, 255, 0),  # 255 - floor(255 / 6) = 213
        21: (0, 255, 0),
        25: (0, 255, 255),
        27: (0, 209, 255),  # 255 - floor(255 * 2 / 11) = 209
        36: (0, 0, 255),
        49: (255, 0, 255),
        54: (255, 0, 43),  # 255 - floor(255 * 5 / 6) = 43
    }
    for k, rgb in expected.items():
        assert tuple(COLOR_WHEEL[k]) == rgb, k


def colour_of(u: float, v: float) -> tuple[int, ...]:
    rgb = flow_to_color(np.array([[[u, v]]], np.float32), max_magnitude=1.0)
    return tuple(int(c) for c in rgb[0, 0])


def test_flow_to_color_hand_computed_values():
    # angle 0 (rightward) at full saturation is wheel entry 0, pure red, for either sign of zero v
    assert colour_of(1.0, 0.0) == (255, 0, 0)
    assert colour_of(1.0, -0.0) == (255, 0, 0)
    # leftward: a = 0, fk = 27 exactly -> wheel entry 27
    assert colour_of(-1.0, 0.0) == (0, 209, 255)
    # downward (y down): a = -0.5, fk = 13.5 -> halfway between (255, 221, 0) and (255, 238, 0)
    assert colour_of(0.0, 1.0) == (255, 229, 0)
    # half saturation: 255 - 0.5 * (255 - c)
    assert colour_of(0.5, 0.0) == (255, 127, 127)
    # beyond max_magnitude: full colour darkened to 75 %
    assert colour_of(2.0, 0.0) == (191, 0, 0)
    assert colour_of(0.0, 0.0) == (255, 255, 255)


def test_flow_to_color_zero_invalid_and_default_scale():
    flow = np.zeros((4, 6, 2), np.float32)
    flow[0, 0] = (4.0, 0.0)  # the largest valid magnitude: full saturation by default
    flow[0, 1] = (1e10, 1e10)  # invalid, must not set the scale
    flow[0, 2] = (np.nan, 0.0)  # non-finite: black even though "valid"
    valid = np.ones((4, 6), bool)
    valid[0, 1] = valid[3, 5] = False
    rgb = flow_to_color(flow, valid)
    assert rgb.dtype == np.uint8 and rgb.shape == (4, 6, 3)
    assert tuple(rgb[0, 0]) == (255, 0, 0)
    assert tuple(rgb[0, 1]) == tuple(rgb[0, 2]) == tuple(rgb[3, 5]) == (0, 0, 0)
    assert (rgb[1:3] == 255).all()
    assert (flow_to_color(np.zeros((3, 2, 2), np.float32)) == 255).all()


def test_flow_to_color_opposite_directions_differ():
    rng = np.random.default_rng(10)
    d = rng.normal(size=(50, 1, 2)).astype(np.float32)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    a = flow_to_color(d, max_magnitude=1.0).astype(int)
    b = flow_to_color(-d, max_magnitude=1.0).astype(int)
    assert (np.abs(a - b).sum(axis=-1) > 100).all()


def test_flow_to_color_bad_input_raises():
    with pytest.raises(ProjsynthError):
        flow_to_color(np.zeros((3, 4, 2), np.float32), max_magnitude=0.0)
    with pytest.raises(ProjsynthError):
        flow_to_color(np.zeros((3, 4), np.float32))
    with pytest.raises(ProjsynthError):
        flow_to_color(np.zeros((3, 4, 2), np.float32), np.ones((3, 4), np.uint8))


def test_docstring_examples():
    assert doctest.testmod(flowio).failed == 0


def test_extra_header_attributes_round_trip_and_cannot_replace_the_format_ones():
    flow = np.zeros((2, 3, 2), np.float32)
    data = encode_flow_exr(flow, np.ones((2, 3), bool), "s0", attrs={"registered": "no", "sample_id": "evil"})
    _, _, header = decode_flow_exr(data)
    assert header["registered"] == "no" and header["sample_id"] == "s0" and header["units"] == "px"


def test_exr_confidence_channel_round_trips_and_is_optional(tmp_path):
    flow = np.random.default_rng(3).normal(0, 5, (6, 7, 2)).astype(np.float32)
    valid = np.ones((6, 7), bool)
    confidence = np.linspace(-0.5, 1.5, 42, dtype=np.float32).reshape(6, 7)  # stored clipped to [0, 1]
    (tmp_path / "c.exr").write_bytes(encode_flow_exr(flow, valid, "s", confidence=confidence))
    f = read_flow_file(tmp_path / "c.exr")
    np.testing.assert_array_equal(f.flow, flow)
    np.testing.assert_array_equal(f.confidence, np.clip(confidence, 0, 1))
    assert decode_flow_file(encode_flow_exr(flow, valid, "s")).confidence is None  # older files: no channel
    with pytest.raises(ProjsynthError, match="confidence must be a finite"):
        encode_flow_exr(flow, valid, "s", confidence=np.full((6, 7), np.nan))
