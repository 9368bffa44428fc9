"""Write an adversarial pair of source folders: pictures a registration tool should refuse or survive.

Usage: python bench/hard_sources.py --out build/hard [--development]

``OUT/natural/`` (photographs of scikit-image, altered) and ``OUT/generated/`` (synthetic artwork),
six of each, so ``projsynth gen --split all`` pairs them into six pairs used in both roles (the
projected content of one role is the surface texture of the other):

* content on part of the frame only: a photograph on the left 40 % or in one quadrant, a flat
  colour elsewhere (``half-astronaut``, ``corner-coffee``);
* near-uniform content: a photograph squeezed into +-4 grey levels (``faint-camera``) and an almost
  blank page with faint text (``nearblank``);
* repetitive patterns: bricks, gravel and grass as they are (``brick``, ``gravel``, ``grass``), a
  checkerboard, a tiled motif and a regular grid of dots (``checker``, ``tiles``, ``dots``);
* strongly textured, striped surfaces: square-wave stripes and a fine sinusoidal grating
  (``stripes``, ``grating``).

``make hard-bench`` renders them with ``--blend physical`` (a non-linear camera response, gamma
1.8-2.4, ambient light up to daylight: low contrast) over 32 transforms. Nothing is downloaded: the
photographs ship in the scikit-image wheel.

``--development`` writes a different dozen of the same kinds instead (a cat on the right half, a
rocket in one quadrant, a faint moon, enlarged bricks, coins, text; stripes every 72 px, an 11 px
grating, 40 px checkers, a motif every 40 px, a hexagonal grid of dots, an almost blank page): the
set the refinement's checks are chosen on, so the adversarial set above stays a test
(docs/history/2026-11-log.md, "Session 12").
"""

import argparse
from pathlib import Path

import cv2
import numpy as np
from real_sources import as_uint8_rgb

H, W = 384, 512


def photo(name: str) -> np.ndarray:
    import skimage.data

    img = as_uint8_rgb(getattr(skimage.data, name)())
    return cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)


def natural() -> dict[str, np.ndarray]:
    half = photo("astronaut")
    half[:, int(0.4 * W) :] = (90, 110, 130)
    corner = np.full((H, W, 3), (200, 190, 170), np.uint8)
    corner[: H // 2, : W // 2] = cv2.resize(photo("coffee"), (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    faint = (128 + (photo("camera").astype(np.float32) - 128) * 4 / 128).round().astype(np.uint8)
    named = {"half-astronaut": half, "corner-coffee": corner, "faint-camera": faint}
    return named | {name: photo(name) for name in ("brick", "gravel", "grass")}


def generated() -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    stripes = np.where(np.sin(2 * np.pi * (x + 0.3 * y) / 24) > 0, 230, 25).astype(np.uint8)
    grating = (128 + 100 * np.sin(2 * np.pi * x / 7)).astype(np.uint8)
    checker = np.where(((x // 32) + (y // 32)) % 2 > 0, 220, 40).astype(np.uint8)
    motif = np.full((48, 48), 200, np.uint8)
    cv2.circle(motif, (24, 24), 14, 40, 3)
    cv2.line(motif, (6, 42), (42, 6), 90, 2)
    tiles = np.tile(motif, (H // 48 + 1, W // 48 + 1))[:H, :W]
    blank = np.full((H, W), 150, np.uint8)
    cv2.putText(blank, "page 3", (40, 70), cv2.FONT_HERSHEY_SIMPLEX, 0.8, 143, 1)
    rng = np.random.default_rng(3)
    dots = np.full((H, W), 235, np.uint8)
    for cy in range(16, H, 32):
        for cx in range(16, W, 32):
            cv2.circle(dots, (cx + int(rng.integers(-2, 3)), cy), 6, 30, -1)
    gray = dict(stripes=stripes, grating=grating, checker=checker, tiles=tiles, nearblank=blank, dots=dots)
    return {k: np.repeat(v[..., None], 3, axis=2) for k, v in gray.items()}


def development_natural() -> dict[str, np.ndarray]:
    half = photo("chelsea")
    half[:, : W // 2] = (150, 120, 100)
    corner = np.full((H, W, 3), (60, 70, 90), np.uint8)
    corner[H // 2 :, W // 2 :] = cv2.resize(photo("rocket"), (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    faint = (128 + (photo("moon").astype(np.float32) - 128) * 5 / 128).round().astype(np.uint8)
    bricks = cv2.resize(photo("brick")[: H // 2 + 40, : W // 2 + 60], (W, H))
    named = {"half-chelsea": half, "corner-rocket": corner, "faint-moon": faint, "bricks-enlarged": bricks}
    return named | {name: photo(name) for name in ("coins", "text")}


def development_generated() -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    stripes = np.where(np.sin(2 * np.pi * (x - 0.5 * y) / 72) > 0, 210, 40).astype(np.uint8)
    grating = (128 + 90 * np.sin(2 * np.pi * y / 11)).astype(np.uint8)
    checker = np.where(((x // 40) + (y // 40)) % 2 > 0, 200, 60).astype(np.uint8)
    motif = np.full((40, 40), 60, np.uint8)
    cv2.rectangle(motif, (8, 8), (31, 31), 220, 2)
    cv2.line(motif, (20, 4), (20, 36), 180, 2)
    tiles = np.tile(motif, (H // 40 + 1, W // 40 + 1))[:H, :W]
    dots = np.full((H, W), 40, np.uint8)
    for row, cy in enumerate(range(20, H, 48)):
        for cx in range(20 + 28 * (row % 2), W, 56):
            cv2.circle(dots, (cx, cy), 9, 220, -1)
    blank = np.full((H, W), 100, np.uint8)
    cv2.line(blank, (60, 300), (450, 280), 106, 1)
    gray = dict(stripes72=stripes, grating11=grating, checker80=checker, tiles40=tiles, lines=blank, hexdots=dots)
    return {k: np.repeat(v[..., None], 3, axis=2) for k, v in gray.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("build/hard"))
    ap.add_argument("--development", action="store_true", help="the development set the checks are chosen on")
    args = ap.parse_args()
    sets = (development_natural(), development_generated()) if args.development else (natural(), generated())
    for kind, images in zip(("natural", "generated"), sets, strict=True):
        folder = args.out / kind
        folder.mkdir(parents=True, exist_ok=True)
        for name, rgb in images.items():
            if not cv2.imwrite(str(folder / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                raise SystemExit(f"hard_sources: cannot write {folder / name}.png")
    which = "development" if args.development else "adversarial"
    print(f"{args.out}: 6 natural, 6 generated {which} pictures")


if __name__ == "__main__":
    main()
