"""``projreg warp`` (projreg.inference.warpfiles, the CLI and the API): each file, read back and applied as
show software applies it, reproduces ``projreg compensate`` of the same flow; bad input is one line, exit
2, nothing written."""

import io

import cv2
import numpy as np
import OpenEXR
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from projreg.api import Registration, compensate, export_warp, warp_map
from projreg.cli import app
from projreg.errors import ProjregError
from projreg.inference.warpfiles import encode_npz, encode_stmap
from projreg.inference.warpmaps import warp_map as flow_warp_map
from projsynth.flow.formats import encode_flow_exr

from .warpcases import CAMERA, H, W, bent_homography, parse_obj, rasterise


def texture(shape, seed=0):
    """A smooth random picture in 20..235, so that a compensated pixel is never the fill (0)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (*shape, 3)).astype(np.float32), (0, 0), 1.5)
    return (20 + (tex - tex.min()) / (tex.max() - tex.min()) * 215).astype(np.uint8)


def flow_file(path, registered="yes", predicted=True):
    """A flow EXR as `projreg predict` writes one (``predicted``; else as another tool): the bent
    homography, claimed on a rectangle, the confidence falling across the frame."""
    flow = bent_homography()
    claimed = np.zeros((H, W), bool)
    claimed[5:40, 10:50] = registered == "yes"
    confidence = np.tile(np.linspace(1, 0, W, dtype=np.float32), (H, 1))
    attrs = {"registered": registered, "camera_size": f"{CAMERA[0]}x{CAMERA[1]}"}
    attrs |= {"valid_threshold": "confidence >= 0.5"} if predicted else {}
    path.write_bytes(encode_flow_exr(flow, claimed, "x", attrs=attrs, confidence=confidence if predicted else None))
    return flow, claimed, confidence


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def compensated(tmp_path, content, *options):
    """``projreg compensate`` of ``content`` through ``f.exr``: the projector image and where it shows content."""
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(content, cv2.COLOR_RGB2BGR))
    result = run(
        "compensate",
        "--content",
        tmp_path / "c.png",
        "--flow",
        tmp_path / "f.exr",
        "--out",
        tmp_path / "p.png",
        *options,
    )
    assert result.exit_code == 0, result.stderr
    image = cv2.cvtColor(cv2.imread(str(tmp_path / "p.png")), cv2.COLOR_BGR2RGB)
    return image, (image != 0).any(axis=2)


def read_stmap(path):
    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = exr.channels()
    assert {name: channels[name].pixels.dtype for name in channels} == dict.fromkeys("RGBA", np.float32)
    return np.stack([channels[c].pixels for c in "RGBA"], -1)


def through_stmap(content, rgba):
    """The content remapped through an STMap as a compositor does: bilinear, replicated border, black
    where A = 0."""
    ch, cw = content.shape[:2]
    x, y = rgba[..., 0] * cw - 0.5, (1 - rgba[..., 1]) * ch - 0.5
    out = cv2.remap(content, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out[rgba[..., 3] == 0] = 0
    return out


def grey_difference(a, b, where):
    return float(np.abs(a.astype(float) - b)[where].mean())


@pytest.mark.parametrize("options", [(), ("--coverage", "claimed"), ("--min-confidence", "0.6")])
def test_the_stmap_reproduces_compensate(tmp_path, options):
    flow, _, _ = flow_file(tmp_path / "f.exr")
    result = run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.exr", *options)
    assert result.exit_code == 0, result.stderr
    rgba = read_stmap(tmp_path / "w.exr")
    for content in (texture(CAMERA), texture((2 * CAMERA[0], 2 * CAMERA[1]), 1)):  # any content size
        want, shown = compensated(tmp_path, content, *options)
        np.testing.assert_array_equal(rgba[..., 3] == 1, shown)  # the same pixels show content
        assert set(np.unique(rgba[..., 3])) == {0.0, 1.0} and (rgba[..., 2] == 0).all()
        assert grey_difference(through_stmap(content, rgba), want, shown) <= 0.05
    y, x = 17, 23  # a pixel against the formula
    u, v = (x + flow[y, x, 0] + 0.5) / CAMERA[1], 1 - (y + flow[y, x, 1] + 0.5) / CAMERA[0]
    np.testing.assert_allclose(rgba[y, x, :2], [u, v], atol=1e-6)
    assert f"{W}x{H} STMap (32-bit float RGBA), content on {shown.mean():.1%}" in result.stderr


def test_a_flow_of_another_tool_shows_content_where_its_valid_says(tmp_path):
    flow_file(tmp_path / "f.exr", predicted=False)
    assert run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.exr").exit_code == 0
    rgba = read_stmap(tmp_path / "w.exr")
    want, shown = compensated(tmp_path, texture(CAMERA))
    np.testing.assert_array_equal(rgba[..., 3] == 1, shown)
    assert not shown[:5].any()  # outside the claimed rectangle


def test_a_pair_not_registered_maps_the_content_as_it_is(tmp_path):
    flow_file(tmp_path / "f.exr", registered="no")
    result = run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.exr")
    assert result.exit_code == 0 and "not registered; the map projects content as it is" in result.stderr
    rgba = read_stmap(tmp_path / "w.exr")
    assert (rgba[..., 3] == 1).all()
    content = texture((H, W))  # the projector's size (and the camera's aspect): compensate's resize is the identity
    want, _ = compensated(tmp_path, content)
    np.testing.assert_array_equal(through_stmap(content, rgba), want)


@pytest.mark.parametrize("step", [4, 8])  # 16 px cells on a 48 x 64 frame this bent: 0.3 px off, 3 grey levels
def test_the_mesh_reproduces_compensate_and_reports_its_error(tmp_path, step):
    flow_file(tmp_path / "f.exr")
    result = run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.obj", "--step", step)
    assert result.exit_code == 0, result.stderr
    v, vt, triangles = parse_obj((tmp_path / "w.obj").read_text())
    drawn = rasterise(v, vt, triangles, (H, W))  # as a renderer draws it
    covered = ~np.isnan(drawn[..., 0])
    content = texture(CAMERA)
    want, shown = compensated(tmp_path, content)
    rgba = np.dstack([np.nan_to_num(drawn, nan=-1.0), np.zeros((H, W)), covered]).astype(np.float32)
    both = covered & shown
    assert both.sum() > 0.5 * shown.sum() and (covered <= shown).all()  # this flow's coverage has no holes
    assert grey_difference(through_stmap(content, rgba), want, both) <= 1.0
    assert run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "full.exr").exit_code == 0
    full = read_stmap(tmp_path / "full.exr")
    d = (drawn - full[..., :2]) * (CAMERA[1], CAMERA[0])
    err = np.hypot(d[..., 0], d[..., 1])[both]
    assert f"interpolation error {err.mean():.3f} px mean, {err.max():.3f} px max" in result.stderr
    assert f"a vertex every {step} px" in result.stderr and f"{len(triangles)} triangles" in result.stderr


@pytest.mark.parametrize("content_size", [None, (2 * CAMERA[0], 2 * CAMERA[1])])
def test_the_npz_maps_reproduce_compensate_with_cv2_remaps_defaults(tmp_path, content_size):
    flow_file(tmp_path / "f.exr")
    size = [] if content_size is None else ["--content-size", f"{content_size[1]}x{content_size[0]}"]
    result = run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.npz", *size)
    assert result.exit_code == 0, result.stderr
    m = np.load(tmp_path / "w.npz")
    assert m["map_x"].dtype == m["map_y"].dtype == np.float32 and m["shown"].dtype == bool
    content = texture(content_size or CAMERA)
    assert tuple(m["content_size"]) == content.shape[:2]
    shown_through = cv2.remap(content, m["map_x"], m["map_y"], cv2.INTER_LINEAR)  # docs/show.md's line
    want, shown = compensated(tmp_path, content)
    np.testing.assert_array_equal(m["shown"], shown)
    assert grey_difference(shown_through, want, shown) <= 0.05 and (shown_through[~shown] == 0).all()
    assert f"cv2.remap maps for {content.shape[1]}x{content.shape[0]} content" in result.stderr


def test_the_api_takes_a_registration_or_a_flow_file(tmp_path):
    flow, claimed, confidence = flow_file(tmp_path / "f.exr")
    reg = Registration(flow, claimed, confidence, True, "", CAMERA)
    content = texture(CAMERA)
    m = warp_map(reg, min_confidence=0.3)
    want = compensate(content, reg, min_confidence=0.3)
    np.testing.assert_array_equal(m.shown, (want != 0).any(axis=2))
    got = through_stmap(content, m.stmap())
    assert grey_difference(got, want, m.shown) <= 0.05
    from_reg = export_warp(reg, tmp_path / "a.obj", step=8)
    from_file = export_warp(tmp_path / "f.exr", tmp_path / "b.obj", step=8)
    assert (tmp_path / "a.obj").read_text() != "" and from_reg["error_max"] == from_file["error_max"] > 0
    assert from_file["registered"] and not from_file["as_it_is"]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--out", "w.png"], "--out w.png: not a warp format (.png); give a name ending in .exr (STMap)"),
        (["--out", "w"], "--out w: not a warp format (no suffix)"),
        (["--out", "w.obj", "--step", "0"], "--step 0: expected an integer in 1..47"),
        (["--out", "w.obj", "--step", "48"], "--step 48: expected an integer in 1..47"),
        (["--out", "w.exr", "--step", "8"], "--step sets the grid of a mesh"),
        (["--out", "w.npz", "--content-size", "big"], "--content-size: expected WxH such as 1920x1080"),
        (["--out", "w.npz", "--content-size", "100x100"], "--content-size is 100x100 px (aspect 1.000)"),
        (["--out", "w.npz", "--content-size", "0x0"], "--content-size: expected two integers in 1..16384"),
        (["--out", "w.obj", "--content-size", "80x60"], "--content-size is for cv2.remap maps (.npz)"),
        (["--out", "w.exr", "--coverage", "verified"], "--coverage must be one of complete, claimed"),
        (["--out", "f.exr"], "--out"),  # onto its input
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, monkeypatch, args, says):
    monkeypatch.chdir(tmp_path)
    flow_file(tmp_path / "f.exr")
    before = (tmp_path / "f.exr").read_bytes()
    result = run("warp", "--flow", "f.exr", *args)
    assert result.exit_code == 2 and says in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.exr"] and (tmp_path / "f.exr").read_bytes() == before


def test_a_file_that_is_not_a_flow_is_one_line_naming_it(tmp_path):
    (tmp_path / "f.exr").write_bytes(b"not an exr")
    result = run("warp", "--flow", tmp_path / "f.exr", "--out", tmp_path / "w.exr")
    assert result.exit_code == 2 and "f.exr: not a valid OpenEXR flow file" in result.stderr
    assert not (tmp_path / "w.exr").exists()
    result = run("warp", "--flow", tmp_path / "missing.exr", "--out", tmp_path / "w.exr")
    assert result.exit_code == 2 and "missing.exr: cannot read" in result.stderr


@settings(max_examples=25, deadline=None)
@given(
    shape=st.tuples(st.integers(2, 12), st.integers(2, 12)),
    shift=st.tuples(st.floats(-1, 1, width=32), st.floats(-1, 1, width=32)),  # some pixel always lands inside
    content=st.tuples(st.integers(1, 40), st.integers(1, 40)),
)
def test_the_files_hold_the_map_bit_for_bit(shape, shift, content):
    m = flow_warp_map(np.broadcast_to(np.array(shift, np.float32), (*shape, 2)))
    exr = OpenEXR.File(io.BytesIO(encode_stmap(m, "a test")), separate_channels=True)
    np.testing.assert_array_equal(np.stack([exr.channels()[c].pixels for c in "RGBA"], -1), m.stmap())
    npz = np.load(io.BytesIO(encode_npz(m, content)))
    map_x, map_y = m.remap_maps(content)
    np.testing.assert_array_equal(npz["map_x"], map_x)
    np.testing.assert_array_equal(npz["map_y"], map_y)
    np.testing.assert_array_equal(npz["shown"], m.shown)
    assert tuple(npz["content_size"]) == content


@pytest.mark.parametrize(
    ("out", "says"), [(None, "got NoneType"), (5, "got int"), (b"w.exr", "got bytes"), ("", "empty")]
)
def test_the_api_refuses_an_out_that_is_not_a_path(tmp_path, out, says):
    flow, claimed, confidence = flow_file(tmp_path / "f.exr")
    reg = Registration(flow, claimed, confidence, True, "", CAMERA)
    for source in (reg, tmp_path / "f.exr"):
        with pytest.raises(ProjregError, match=rf"^out: .*{says}"):
            export_warp(source, out)
    assert [p.name for p in tmp_path.iterdir()] == ["f.exr"]


@pytest.mark.parametrize("min_confidence", ["0.5", None, True, float("nan")])
def test_the_api_refuses_a_min_confidence_that_is_not_a_number_in_0_1(tmp_path, min_confidence):
    flow, claimed, confidence = flow_file(tmp_path / "f.exr")
    reg = Registration(flow, claimed, confidence, True, "", CAMERA)
    calls = (
        lambda: warp_map(reg, min_confidence=min_confidence),
        lambda: export_warp(reg, tmp_path / "w.exr", min_confidence=min_confidence),
        lambda: compensate(texture(CAMERA), reg, min_confidence=min_confidence),
    )
    for call in calls:  # a string and None raised a raw TypeError; True was read as 1
        with pytest.raises(ProjregError, match=r"^--min-confidence: expected a number in \[0, 1\]"):
            call()
    assert warp_map(reg, min_confidence=np.float32(0.3)).shown.sum() == warp_map(reg, min_confidence=0.3).shown.sum()


def test_the_api_refuses_a_content_size_that_is_not_two_integers(tmp_path):
    flow, claimed, confidence = flow_file(tmp_path / "f.exr")
    reg = Registration(flow, claimed, confidence, True, "", CAMERA)
    for bad in (60, (60.0, 80), (60, 80, 3), (True, 80)):
        with pytest.raises(ProjregError, match="--content-size: expected two integers"):
            export_warp(reg, tmp_path / "w.npz", content_size=bad)
    assert not (tmp_path / "w.npz").exists()
    assert export_warp(reg, tmp_path / "w.npz", content_size=[120, 160])["content_size"] == (120, 160)
