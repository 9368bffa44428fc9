"""Write scikit-image's bundled pictures as a held-out source folder pair (real photographs x artwork).

Usage: python bench/real_sources.py --out build/real

``OUT/natural/``: the bundled photographs; ``OUT/generated/``: the bundled graphics and drawings
(logo, colour wheel, scanned text, a page, a silhouette, a phantom). None of them is used to train the
reference model (it sees built-in procedural images only), so

    projsynth gen --out build/real-test --natural build/real/natural --generated build/real/generated \
        --split all --seed 5 --transforms ...

is a test set of real pictures the model has never seen (``make real-bench``). The pictures ship
inside the scikit-image wheel (the ``samples`` extra): nothing is downloaded, and nothing is
committed to this repository. Provenance: docs/history/2026-11-log.md.
"""

import argparse
from pathlib import Path

import cv2
import numpy as np

# ``cat`` is the same picture as ``chelsea``; ``retina`` and ``hubble_deep_field`` are mostly black
PHOTOGRAPHS = (
    "astronaut",
    "brick",
    "camera",
    "chelsea",
    "clock",
    "coffee",
    "coins",
    "grass",
    "gravel",
    "immunohistochemistry",
    "moon",
    "rocket",
)
ARTWORK = ("logo", "colorwheel", "text", "page", "horse", "shepp_logan_phantom", "binary_blobs")
SEEDED = {"binary_blobs": {"rng": 0}}  # drawn at random on each call: seeded, so the set is the same each time


def as_uint8_rgb(image: np.ndarray) -> np.ndarray:
    """Any scikit-image sample (bool, float in [0, 1], gray, RGB, RGBA over white) as ``H x W x 3`` uint8."""
    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    elif a.dtype.kind == "f":
        a = (np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.shape[2] == 4:  # composite over white: a logo's transparent background is paper, not black
        alpha = a[..., 3:].astype(np.float32) / 255
        a = (a[..., :3] * alpha + 255 * (1 - alpha) + 0.5).astype(np.uint8)
    return np.ascontiguousarray(a)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("build/real"))
    args = ap.parse_args()
    import skimage.data

    for kind, names in (("natural", PHOTOGRAPHS), ("generated", ARTWORK)):
        folder = args.out / kind
        folder.mkdir(parents=True, exist_ok=True)
        for name in names:
            rgb = as_uint8_rgb(getattr(skimage.data, name)(**SEEDED.get(name, {})))
            if not cv2.imwrite(str(folder / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                raise SystemExit(f"real_sources: cannot write {folder / name}.png")
    print(f"{args.out}: {len(PHOTOGRAPHS)} photographs, {len(ARTWORK)} artworks")


if __name__ == "__main__":
    main()
