import dataclasses
import hashlib
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from projsynth import ProjsynthError
from projsynth.content.sources import (
    MIN_SOURCE_SIDE,
    SPLITS,
    FolderSource,
    SourceImage,
    fit_to_size,
    scene_label,
    split_of,
)
from projsynth.utils.images import IMAGE_EXTENSIONS, list_images, load_image


def rgb_image(h: int = 40, w: int = 56, seed: int = 0) -> np.ndarray:
    img = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    img[3, 5] = (10, 20, 200)  # a known, strongly blue RGB pixel
    return img


def write(path: Path, image: np.ndarray, params: tuple[int, ...] = ()) -> Path:
    """Write with OpenCV, which expects BGR(A) channel order."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR if image.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), image, list(params))
    return path


def png_gray_alpha(gray: np.ndarray, alpha: np.ndarray) -> bytes:
    """A minimal 8-bit gray + alpha PNG (colour type 4), which cv2.imwrite cannot produce."""
    h, w = gray.shape
    rows = np.stack([gray, alpha], -1).astype(np.uint8).reshape(h, 2 * w)
    raw = b"".join(b"\x00" + row.tobytes() for row in rows)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", w, h, 8, 4, 0, 0, 0)
    body = chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


# --- load_image: normalisation to RGB uint8 ----------------------------------------------------


@pytest.mark.parametrize("name", ["a.png", "a.bmp", "a.tif", "a.tiff", "a.webp"])
def test_lossless_formats_round_trip_exactly(tmp_path, name):
    img = rgb_image()
    params = (cv2.IMWRITE_WEBP_QUALITY, 101) if name.endswith(".webp") else ()  # > 100: lossless webp
    out = load_image(write(tmp_path / name, img, params))
    assert out.dtype == np.uint8 and out.shape == img.shape
    np.testing.assert_array_equal(out, img)
    assert tuple(out[3, 5]) == (10, 20, 200)  # RGB, not BGR


def test_jpeg_keeps_channel_order(tmp_path):
    img = np.zeros((64, 64, 3), np.uint8)
    img[:, :32] = (220, 30, 30)  # red left half
    img[:, 32:] = (30, 30, 220)  # blue right half
    out = load_image(write(tmp_path / "a.JPG", img, (cv2.IMWRITE_JPEG_QUALITY, 95)))
    assert out.shape == (64, 64, 3) and out.dtype == np.uint8
    assert np.abs(out[8:56, 4:28].astype(int) - (220, 30, 30)).max() < 8
    assert np.abs(out[8:56, 36:60].astype(int) - (30, 30, 220)).max() < 8


def test_16bit_rounds_v_over_257(tmp_path):
    values = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    out = load_image(write(tmp_path / "a16.png", values))
    expected = np.floor(values / 257 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(out, np.repeat(expected[..., None], 3, axis=2))
    assert out[-1, -1, 0] == 255 and out[0, 128, 0] == 0 and out[0, 129, 0] == 1


def test_16bit_rgba_tiff(tmp_path):
    img = np.zeros((40, 40, 4), np.uint16)
    img[..., 0], img[..., 1], img[..., 2], img[..., 3] = 65535, 257 * 100, 0, 1234  # RGBA
    out = load_image(write(tmp_path / "a.tiff", img))
    np.testing.assert_array_equal(out[0, 0], (255, 100, 0))


def test_gray_is_replicated(tmp_path):
    g = rgb_image()[..., 0]
    out = load_image(write(tmp_path / "g.png", g))
    assert out.shape == (*g.shape, 3)
    for c in range(3):
        np.testing.assert_array_equal(out[..., c], g)


def test_gray_alpha_drops_alpha(tmp_path):
    g = rgb_image()[..., 1]
    path = tmp_path / "ga.png"
    path.write_bytes(png_gray_alpha(g, np.zeros_like(g)))
    np.testing.assert_array_equal(load_image(path), np.repeat(g[..., None], 3, axis=2))


def test_rgba_drops_alpha_without_compositing(tmp_path):
    img = rgb_image()
    rgba = np.concatenate([img, np.zeros((*img.shape[:2], 1), np.uint8)], axis=2)  # fully transparent
    np.testing.assert_array_equal(load_image(write(tmp_path / "a.png", rgba)), img)


def test_float_tiff_is_clipped_and_scaled(tmp_path):
    f = np.array([[-0.5, 0.0, 0.5, 1.0, 2.0, np.nan]], np.float32).repeat(3, 0)
    out = load_image(write(tmp_path / "f.tiff", f))
    np.testing.assert_array_equal(out[0, :, 0], [0, 0, 128, 255, 255, 0])


def test_unicode_path(tmp_path):
    img = rgb_image()
    path = tmp_path / "ünï cødé" / "画像.png"
    path.parent.mkdir()
    cv2.imencode(".png", img[..., ::-1])[1].tofile(path)
    np.testing.assert_array_equal(load_image(path), img)


def bad_files(tmp_path: Path) -> dict[str, Path]:
    good = cv2.imencode(".png", rgb_image())[1].tobytes()
    files = {"truncated": good[:100], "empty": b"", "text": b"this is not an image\n"}
    out = {}
    for name, data in files.items():
        out[name] = tmp_path / f"{name}.png"
        out[name].write_bytes(data)
    return out


@pytest.mark.parametrize("name", ["truncated", "empty", "text", "missing"])
def test_unreadable_files_raise_with_path(tmp_path, name):
    path = bad_files(tmp_path).get(name, tmp_path / "missing.png")
    with pytest.raises(ProjsynthError, match="cannot read image") as err:
        load_image(path)
    assert str(path) in str(err.value)
    assert ("check the path" if name == "missing" else "remove it or fix it") in str(err.value)


def test_a_folder_with_no_readable_image_names_the_folder_and_why(tmp_path):
    from projsynth.dataset.plan import resolve_plan

    (tmp_path / "nat").mkdir()
    for name in ("a", "b", "c"):
        (tmp_path / "nat" / f"{name}.png").write_bytes(b"not a png")
    (tmp_path / "gen").mkdir()
    for i in range(4):
        cv2.imwrite(str(tmp_path / "gen" / f"g{i}.png"), np.full((40, 40, 3), 60 * i, np.uint8))
    with pytest.raises(ProjsynthError) as err:
        resolve_plan(
            size=(32, 32),
            seed=0,
            split="all",
            pairs=1,
            transforms="0",
            blend="paper",
            natural=tmp_path / "nat",
            generated=tmp_path / "gen",
        )
    msg = str(err.value)
    assert msg.startswith("--natural: the all split has only 0 usable natural image(s) for 1 pair(s); 3 unreadable")
    assert re.search(r"nat/[abc]\.png: cannot read image", msg) and msg.endswith("; add images to the folder")


# --- fit_to_size ---------------------------------------------------------------------------------


@pytest.mark.parametrize("src", [(40, 56), (300, 100), (100, 300), (384, 512), (1000, 1000)])
@pytest.mark.parametrize("size", [(384, 512), (64, 64), (48, 200)])
def test_fit_shape_dtype_and_determinism(src, size):
    img = rgb_image(*src)
    out = fit_to_size(img, size)
    assert out.shape == (*size, 3) and out.dtype == np.uint8 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, fit_to_size(img, size))


def test_fit_crops_the_centre():
    wide = np.zeros((100, 400, 3), np.uint8)
    wide[:, :100], wide[:, 100:300], wide[:, 300:] = (255, 0, 0), (0, 255, 0), (255, 0, 0)
    np.testing.assert_array_equal(fit_to_size(wide, (64, 64)), np.full((64, 64, 3), (0, 255, 0), np.uint8))
    tall = np.ascontiguousarray(wide.transpose(1, 0, 2))  # 400 x 100: red top and bottom quarters
    np.testing.assert_array_equal(fit_to_size(tall, (50, 50)), np.full((50, 50, 3), (0, 255, 0), np.uint8))


def test_fit_crop_offsets_and_interpolation():
    img = rgb_image(50, 91)
    np.testing.assert_array_equal(fit_to_size(img, (50, 50)), img[:, 20:70])  # (91 - 50) // 2 = 20
    np.testing.assert_array_equal(
        fit_to_size(img, (25, 25)), cv2.resize(img[:, 20:70], (25, 25), interpolation=cv2.INTER_AREA)
    )
    np.testing.assert_array_equal(
        fit_to_size(img, (120, 120)), cv2.resize(img[:, 20:70], (120, 120), interpolation=cv2.INTER_CUBIC)
    )
    # 50 x 91 to 2:1 -> crop 46 x 91 rows 2..47 (round(91 / 2) = 46), then enlarge.
    np.testing.assert_array_equal(fit_to_size(img, (46, 91)), img[2:48])


@pytest.mark.parametrize("shape", [(10, 10), (MIN_SOURCE_SIDE - 1, 100), (100, MIN_SOURCE_SIDE - 1)])
def test_fit_rejects_tiny_images(shape):
    with pytest.raises(ProjsynthError, match="too small") as err:
        fit_to_size(np.zeros((*shape, 3), np.uint8), (64, 64), name="tiny.png")
    assert "tiny.png" in str(err.value)


def test_fit_accepts_the_minimum():
    assert fit_to_size(rgb_image(MIN_SOURCE_SIDE, MIN_SOURCE_SIDE), (64, 80)).shape == (64, 80, 3)


# --- listing, labels, splits ---------------------------------------------------------------------


def test_list_images_recursive_sorted_case_insensitive(tmp_path):
    img = rgb_image()
    for rel in ["b/a.png", "a.PNG", "a/z.JpEg", "B.bmp", "a/deep/x.TIFF", "c.webp", "d.tif"]:
        write(tmp_path / rel, img)
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "a" / ".hidden.png").write_bytes(b"")
    (tmp_path / "._resource.png").write_bytes(b"")
    found = [p.relative_to(tmp_path).as_posix() for p in list_images(tmp_path, "--natural")]
    assert found == ["B.bmp", "a.PNG", "a/deep/x.TIFF", "a/z.JpEg", "b/a.png", "c.webp", "d.tif"]
    assert set(IMAGE_EXTENSIONS) == {".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff"}


def test_list_images_bad_folders(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "text").mkdir()
    (tmp_path / "text" / "a.txt").write_text("x")
    (tmp_path / "file.png").write_bytes(b"x")
    for folder, message in [
        ("empty", "no images"),
        ("text", "no images"),
        ("missing", "does not exist"),
        ("file.png", "not a folder"),
    ]:
        with pytest.raises(ProjsynthError, match=message) as err:
            list_images(tmp_path / folder, "--generated")
        assert "--generated" in str(err.value) and str(tmp_path / folder) in str(err.value)


def test_scene_label(tmp_path):
    assert scene_label(tmp_path / "Forest" / "x.png", tmp_path) == "forest"
    assert scene_label(tmp_path / "urban" / "sub" / "x.png", tmp_path) == "urban"
    assert scene_label(tmp_path / "cats" / "ocean" / "x.png", tmp_path) is None
    assert scene_label(tmp_path / "ocean.png", tmp_path) is None


def test_split_shares_stability_and_hash():
    names = [f"dir{i % 7}/img_{i:05d}.png" for i in range(2000)]
    splits = [split_of(n, 3) for n in names]
    shares = {s: splits.count(s) / len(names) for s in SPLITS}
    assert abs(shares["train"] - 0.8) < 0.03
    assert abs(shares["val"] - 0.1) < 0.02 and abs(shares["test"] - 0.1) < 0.02
    assert splits == [split_of(n, 3) for n in names]  # stable; depends on nothing but (seed, name)
    assert np.mean([a != split_of(n, 4) for n, a in zip(names, splits, strict=True)]) > 0.2  # seed matters
    u = int(hashlib.sha256(b"3:dir0/img_00000.png").hexdigest()[:16], 16) / 2**64
    assert splits[0] == ("train" if u < 0.8 else "val" if u < 0.9 else "test")


def make_tree(root: Path, n: int = 40) -> None:
    for i in range(n):
        theme = ["urban", "Ocean", "misc", ""][i % 4]
        write(root / theme / f"img{i:03d}.png", rgb_image(40 + i, 60, seed=i))


def test_folder_source_splits_are_disjoint_complete_and_shuffled(tmp_path):
    make_tree(tmp_path)
    source = FolderSource(tmp_path, "natural", "--natural")
    disjoint = ("train", "val", "test")
    parts = {s: source.files_for_split(s, seed=5) for s in SPLITS}
    names = [im.name for s in disjoint for im in parts[s]]
    assert sorted(names) == sorted(im.name for im in source.images) and len(set(names)) == 40
    assert sorted(im.name for im in parts["all"]) == sorted(names)  # a held-out folder, used whole
    assert [im.name for im in parts["train"]] != sorted(im.name for im in parts["train"])
    again = FolderSource(tmp_path, "natural", "--natural").files_for_split("train", seed=5)
    assert again == parts["train"]
    first = source.images[0]
    assert first.kind == "natural" and first.path == tmp_path / first.name
    assert {im.theme for im in source.images} == {"urban", "ocean", None}
    with pytest.raises(ProjsynthError, match="split 'dev'"):
        source.files_for_split("dev", 0)


def test_adding_files_does_not_move_existing_ones(tmp_path):
    make_tree(tmp_path, 20)

    def splits():
        images = FolderSource(tmp_path, "generated", "--generated").images
        return {im.name: split_of(im.name, 1) for im in images}

    before = splits()
    write(tmp_path / "new" / "extra.png", rgb_image())
    after = splits()
    assert {k: after[k] for k in before} == before and len(after) == 21


def test_folder_source_load_and_skip_policy(tmp_path):
    make_tree(tmp_path, 4)
    bad = bad_files(tmp_path)
    write(tmp_path / "tiny.png", rgb_image(10, 10))
    source = FolderSource(tmp_path, "generated", "--generated")
    loaded, skipped = 0, []
    for item in source.images:
        try:
            img = source.load(item, (64, 96))
        except ProjsynthError as err:
            skipped.append(str(err))
            continue
        assert img.shape == (64, 96, 3) and img.dtype == np.uint8
        loaded += 1
    assert loaded == 4 and len(skipped) == 4
    for path in [*bad.values(), tmp_path / "tiny.png"]:
        assert sum(str(path) in message for message in skipped) == 1
    assert any("too small" in message for message in skipped)


def test_source_image_is_frozen():
    src = SourceImage("natural", "a.png", None, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        src.name = "b.png"
    with pytest.raises(ProjsynthError, match="kind 'photo'"):
        FolderSource(Path("."), "photo", "--natural")


# --- scikit-image's pictures, the offline photographs (bench/real_sources.py) ----------------------


def test_real_sources_script_writes_folders_that_gen_uses_whole(tmp_path):
    pytest.importorskip("skimage")
    from projsynth.dataset.plan import resolve_plan

    script = Path(__file__).parents[3] / "bench" / "real_sources.py"
    for out in (tmp_path, tmp_path / "again"):
        done = subprocess.run([sys.executable, str(script), "--out", str(out)], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    for kind in ("natural", "generated"):  # the same pictures each time (binary_blobs draws at random unseeded)
        for path in (tmp_path / kind).iterdir():
            assert path.read_bytes() == (tmp_path / "again" / kind / path.name).read_bytes(), path.name
    natural = list_images(tmp_path / "natural", "--natural")
    generated = list_images(tmp_path / "generated", "--generated")
    assert (len(natural), len(generated)) == (12, 7)
    plan = resolve_plan(
        size=(96, 128),
        seed=5,
        split="all",
        pairs=None,
        transforms="0",
        blend="paper",
        natural=tmp_path / "natural",
        generated=tmp_path / "generated",
    )
    assert plan.pairs == 7 and not plan.skipped  # every picture loads; pairs = the smaller folder
    for path in natural + generated:
        img = load_image(path)
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) >= 128
        assert img.std() > 10  # a picture, not a blank or all-black frame
