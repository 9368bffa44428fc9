"""The paper's real-world protocol (its section 5.3, Table 4), on the virtual rig: ``make real-protocol``.

Usage:
    python bench/real_protocol.py prepare --out build/real-protocol
    projreg bench --data build/real-protocol/SURFACE-TRUTH ... --json build/real-protocol/SURFACE-TRUTH.json
    python bench/real_protocol.py table build/real-protocol > build/real-protocol/table.md

``prepare`` builds two rigs like the paper's: a concave surface with a textured heart-like
interference on it, and a convex surface with a brightened centre (the surfaces as the camera sees
them are drawn here; the geometry is a row of the transform table). For each, the paper's 11 dot
patterns (20 x 20 grid) are photographed and decoded into 400 correspondences, and scikit-image's
photographs are projected and photographed from the same pose. Two datasets per surface hold the same
pairs: ``SURFACE-dots`` with the decoded dots as ground truth (what a real rig measures) and
``SURFACE-exact`` with the simulator's exact dense truth. Benchmarks on both show whether the dots'
error is far below the errors being ranked. ``table`` renders the JSON reports side by side.
"""

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import read_flow_exr
from projsynth.structured.capture import capture
from projsynth.structured.captured import captured_samples, write_captured_dataset
from projsynth.structured.decode import decode_folder
from projsynth.structured.patterns import make_set, write_patterns

PROJECTOR, CAMERA = (384, 512), (480, 640)
SURFACES = {"concave": 110, "convex": 90}  # sphere_concave-s3-studio, sphere_convex-s3-studio
PICTURES = ("astronaut", "chelsea", "coffee", "rocket", "clock", "brick")


def heart_interference(size: tuple[int, int]) -> np.ndarray:
    """A grey-beige surface with a heart-shaped patch of dark stripes on it (camera frame, RGB uint8)."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = (xs - w / 2) / (0.28 * w), -(ys - h / 2) / (0.28 * h)
    heart = (x * x + y * y - 1) ** 3 - x * x * y**3 <= 0
    stripes = 0.5 + 0.5 * np.sin((xs + ys) / 3.5)
    base = np.array([205, 195, 180], np.float64) * (0.9 + 0.1 * np.sin(xs / 40.0) * np.cos(ys / 55.0))[..., None]
    img = np.where(heart[..., None], base * (0.35 + 0.5 * stripes[..., None]), base)
    return np.clip(img, 0, 255).astype(np.uint8)


def brightened_centre(size: tuple[int, int]) -> np.ndarray:
    """A mid-grey surface whose centre is much brighter (a hot spot), camera frame, RGB uint8."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = ((xs - w / 2) / (0.3 * w)) ** 2 + ((ys - h / 2) / (0.3 * h)) ** 2
    level = 120 + 130 * np.exp(-r2)
    return np.clip(np.stack([level, level * 0.97, level * 0.92], -1), 0, 255).astype(np.uint8)


def prepare(out: Path) -> None:
    import skimage.data

    sys.path.insert(0, str(Path(__file__).parent))
    from real_sources import as_uint8_rgb

    pictures = out / "pictures"
    pictures.mkdir(parents=True, exist_ok=True)
    for name in PICTURES:
        rgb = as_uint8_rgb(getattr(skimage.data, name)())
        cv2.imwrite(str(pictures / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    patterns = make_set("dots", PROJECTOR, (20, 20))
    write_patterns(patterns, out / "patterns")
    table = builtin_table()
    for surface, tid in SURFACES.items():
        bg = heart_interference(CAMERA) if surface == "concave" else brightened_centre(CAMERA)
        cv2.imwrite(str(out / f"{surface}-surface.png"), cv2.cvtColor(bg, cv2.COLOR_RGB2BGR))
        rig = out / f"{surface}-rig"
        capture(
            patterns,
            rig,
            table=table,
            transform=tid,
            seed=4,
            camera_size=CAMERA,
            contents=[pictures / f"{n}.png" for n in PICTURES],
            background=out / f"{surface}-surface.png",
        )
        photos = rig / "photos"
        photos.mkdir(exist_ok=True)
        for name in patterns.names:
            (photos / f"{name}.png").write_bytes((rig / f"{name}.png").read_bytes())
        pairs = [(rig / "content" / f"{n}-projected.png", rig / "content" / f"{n}.png") for n in PICTURES]
        print(decode_folder(out / "patterns", photos, out / f"{surface}-dots", pairs))
        flow, valid, _ = read_flow_exr(rig / "truth.exr")
        exact = captured_samples(pairs, flow, valid, CAMERA)
        files = [photos / f"{n}.png" for n in patterns.names]
        write_captured_dataset(out / f"{surface}-exact", patterns, out / "patterns", files, exact, CAMERA)
        dots, dots_valid, _ = read_flow_exr(out / f"{surface}-dots" / "correspondence.exr")
        both = dots_valid & valid
        err = np.hypot(*(dots - flow)[both].T)
        print(f"{surface}: {both.sum()} dots decoded, error mean {err.mean():.3f} px, max {err.max():.3f} px")
        (out / f"{surface}-dots-error.json").write_text(
            json.dumps({"dots": int(both.sum()), "mean_px": float(err.mean()), "max_px": float(err.max())})
        )


def table(out: Path) -> str:
    """Markdown: per surface, each method's EPE and buckets on the decoded dots beside the exact truth."""
    lines = []
    for surface in SURFACES:
        err = json.loads((out / f"{surface}-dots-error.json").read_text())
        lines += [
            f"### {surface} ({err['dots']} dots decoded, their error vs exact truth: mean {err['mean_px']:.3f} px, "
            f"max {err['max_px']:.3f} px)",
            "",
            "| method | EPE dots | s0-10 | s10-40 | s40+ | EPE exact dense | s0-10 | s10-40 | s40+ |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        reports = [json.loads((out / f"{surface}-{gt}.json").read_text()) for gt in ("dots", "exact")]
        for a, b in zip(*(r["results"] for r in reports), strict=True):
            cells = [_fmt(r.get(k)) for r in (a, b) for k in ("epe", "s0-10", "s10-40", "s40+")]
            lines.append(f"| {a['name']} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _fmt(v: float | None) -> str:
    return "–" if v is None else f"{v:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("step", choices=("prepare", "table"))
    ap.add_argument("out", nargs="?", type=Path, default=Path("build/real-protocol"))
    ap.add_argument("--out", dest="out_opt", type=Path)
    args = ap.parse_args()
    out = args.out_opt or args.out
    if args.step == "prepare":
        prepare(out)
    else:
        print(table(out))


if __name__ == "__main__":
    main()
