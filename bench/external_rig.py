"""Issue 16's check on pairs projsynth did not make: ``projreg predict`` as a user runs it, per pair,
against SIFT + RANSAC and DIS medium on the same pairs.

Usage: python bench/external_rig.py --out build/external [--size 384x512] [--limit N] [--json F] [--markdown F]

The rig is written here from scratch (numpy and OpenCV only, nothing from ``projsynth``), so its truth
is independent of the simulator the network was trained on:

* **Geometry**: a forward map ``F`` from projector pixel ``p`` to camera pixel ``q``: a homography
  (keystone, rotation, shift up to 60 px) followed by one of a sinusoidal bend (a warped sheet), a
  dome, a camera lens (radial distortion) or a fold (two planes meeting at a vertical edge); on request
  (``--shape bumps``, not in the rotation) a dozen bumps and dents a few tens of pixels wide. The
  captured image is rendered by inverting ``F`` at every camera pixel (Newton's method, to 1e-4 px);
  the ground-truth flow is ``F(p) - p``, valid where ``F(p)`` falls inside the camera frame.
* **Light**: the projected sRGB picture is linearised (gamma 2.2), mixed by a colour cross-talk
  matrix, multiplied by the surface's albedo (plain, stripes painted on the wall, a blotchy plaster
  texture, or a brick photograph) with ambient light added (night to daylight) and vignetting, blurred
  by defocus, and mapped through a camera response (gamma 1/2.2, an S-curve, or a clipped linear
  one) with sensor noise. Outside the projection the camera sees only the ambient-lit wall.
* **Content**: scikit-image's photographs and artworks (the ``samples`` extra; never seen in
  training), full frame; three of them on the left 45 % of the frame only (a flat colour elsewhere);
  one almost blank page (faint text), which must be reported as not registered.

Metrics per pair (``V``: pixels with ground truth; ``C``: the pixels ``predict`` marks valid in its
EXR): the pipeline's EPE on ``V & C`` and on all of ``V``, the claimed share ``|V & C| / |V|``; each
baseline's EPE on ``V`` and on ``V & C``; the **ratio** = pipeline EPE on ``V & C`` / the best
baseline's EPE on the same pixels (issue 16's target: <= 1.5 on every pair, claimed >= 70 % on
average, mean per-pair EPE <= half the best baseline's; textureless pairs reported).

Times (on an idle machine only): ``predict_seconds``, the wall time of the one ``projreg predict`` folder
call (start-up, model loading, reading the images and writing the flows included), and
``baseline_seconds``, each baseline's time over the pairs in this process (``<name>_seconds`` per pair).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_sources import as_uint8_rgb  # noqa: E402

PICTURES = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "camera",
    "coins",
    "clock",
    "immunohistochemistry",
    "page",
    "text",
    "logo",
    "horse",
    "colorwheel",
    "moon",
)
ONE_SIDED = ("astronaut", "coffee", "rocket")
SHAPES = ("bend", "dome", "lens", "fold")
MORE_SHAPES = ("bumps",)  # only asked for by --shape (the rotation above stays as recorded)
ALBEDOS = ("plain", "stripes", "plaster", "brick")
MORE_ALBEDOS = ("plaid",)  # only asked for by --albedo (the rotation above stays as recorded)
RESPONSES = ("gamma", "s-curve", "linear")
AMBIENTS = (0.0, 0.08, 0.25, 0.5)  # ambient light on the wall, relative to the projector's white


@dataclass(frozen=True)
class Pair:
    """One rendered pair: its name, the picture, the rig's settings and the truth."""

    name: str
    projected: np.ndarray
    captured: np.ndarray
    flow: np.ndarray  # float32 (H, W, 2), forward, projected -> captured
    valid: np.ndarray  # bool (H, W): F(p) inside the camera frame
    settings: dict


def cover(image: np.ndarray, h: int, w: int) -> np.ndarray:
    """Scale ``image`` to cover ``h x w`` and crop its centre."""
    ih, iw = image.shape[:2]
    s = max(h / ih, w / iw)
    big = cv2.resize(image, (max(w, round(iw * s)), max(h, round(ih * s))), interpolation=cv2.INTER_AREA)
    y0, x0 = (big.shape[0] - h) // 2, (big.shape[1] - w) // 2
    return np.ascontiguousarray(big[y0 : y0 + h, x0 : x0 + w])


def picture(name: str, h: int, w: int) -> np.ndarray:
    import skimage.data

    return cover(as_uint8_rgb(getattr(skimage.data, name)()), h, w)


def random_homography(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Corners moved by a keystone (up to 7 % of the side each), a rotation (up to 4 degrees), a scale
    (0.85-1.1) and a shift (up to 60 px): from sub-pixel to s40+ displacements."""
    c = np.float32([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]])
    centre = c.mean(axis=0)
    a, s = np.deg2rad(rng.uniform(-4, 4)), rng.uniform(0.85, 1.1)
    rot = s * np.float32([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    shift = rng.uniform(-1, 1, 2) * rng.choice([4.0, 20.0, 60.0])
    d = (c - centre) @ rot.T + centre + shift + rng.uniform(-0.07, 0.07, (4, 2)) * [w, h]
    return cv2.getPerspectiveTransform(c, d.astype(np.float32)).astype(np.float64)


def surface_map(shape: str, rng: np.random.Generator, h: int, w: int):
    """The non-planar part of ``F``, a function of camera-frame points ``q`` (float64 ``(..., 2)``)."""
    centre, size = np.array([w / 2, h / 2]), float(max(h, w))
    if shape == "bend":
        amp, period = rng.uniform(3, 8), rng.uniform(180, 360)
        k = 2 * np.pi / period
        return lambda q: q + amp * np.stack([np.sin(k * q[..., 1]), np.sin(k * q[..., 0])], axis=-1)
    if shape == "dome":
        depth = rng.uniform(0.03, 0.07) * rng.choice([-1, 1])

        def dome(q):
            d = (q - centre) / size
            return q + depth * size * d * np.exp(-4 * (d**2).sum(axis=-1, keepdims=True))

        return dome
    if shape == "lens":
        k1 = rng.uniform(-0.12, 0.08)
        return lambda q: centre + (q - centre) * (1 + k1 * (((q - centre) / size) ** 2).sum(axis=-1, keepdims=True))
    if shape == "bumps":  # a dozen round bumps and dents, seen with a parallax along one direction
        centres = rng.uniform([0, 0], [w, h], (12, 2))
        heights, widths = rng.uniform(4, 9, 12) * rng.choice([-1, 1], 12), rng.uniform(0.06, 0.1, 12) * size
        angle = rng.uniform(0, 2 * np.pi)
        along = np.array([np.cos(angle), np.sin(angle)])

        def bumps(q):
            d2 = ((q[..., None, :] - centres) ** 2).sum(axis=-1)
            depth = (heights * np.exp(-d2 / (2 * widths**2))).sum(axis=-1, keepdims=True)
            return q + depth * along

        return bumps
    if shape == "fold":  # two planes meeting at a vertical edge: a kink of the slope there
        edge, slope = rng.uniform(0.35, 0.65) * w, rng.uniform(0.04, 0.09) * rng.choice([-1, 1])
        return lambda q: q + np.stack([slope * np.abs(q[..., 0] - edge), 0 * q[..., 1]], axis=-1)
    raise ValueError(shape)


def apply_h(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    hp = p @ H[:, :2].T + H[:, 2]
    return hp[..., :2] / hp[..., 2:]


def invert(forward, q: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``p`` with ``forward(p) = q`` (Newton's method, central-difference Jacobian), to < 1e-4 px."""
    p, e = start.copy(), 1e-3
    for _ in range(30):
        r = forward(p) - q
        if np.abs(r).max() < 1e-5:
            break
        jx = (forward(p + [e, 0]) - forward(p - [e, 0])) / (2 * e)
        jy = (forward(p + [0, e]) - forward(p - [0, e])) / (2 * e)
        det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
        dx = (jy[..., 1] * r[..., 0] - jy[..., 0] * r[..., 1]) / det
        dy = (jx[..., 0] * r[..., 1] - jx[..., 1] * r[..., 0]) / det
        p = p - np.stack([dx, dy], axis=-1)
    if np.abs(forward(p) - q).max() > 1e-4:
        raise RuntimeError("external_rig: the forward map did not invert to 1e-4 px")
    return p


def albedo(kind: str, rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """The wall's reflectance in the camera frame, float32 ``(H, W, 3)`` in (0, 1]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    if kind == "plain":
        a = np.ones((h, w), np.float32) * 0.9
    elif kind == "stripes":  # painted stripes, soft-edged
        period, tilt = rng.uniform(20, 60), rng.uniform(-0.5, 0.5)
        a = 0.6 + 0.3 * np.tanh(3 * np.sin(2 * np.pi * (x + tilt * y) / period))
    elif kind == "plaster":
        a = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 6)
        a = 0.75 + 0.2 * a / np.abs(a).max()
    elif kind == "plaid":  # a woven tartan: dark and light bands crossing at two periods, hard-edged
        period, a = rng.uniform(24, 48), np.zeros((h, w), np.float32)
        for axis in (x, y):
            a += 0.22 * (np.sin(2 * np.pi * axis / period) > 0.3) + 0.12 * (np.sin(2 * np.pi * axis / (period / 3)) > 0)
        a = 0.2 + a
    elif kind == "brick":
        a = 0.35 + 0.65 * picture("brick", h, w)[..., 0].astype(np.float32) / 255
    else:
        raise ValueError(kind)
    tint = rng.uniform(0.85, 1.0, 3).astype(np.float32)
    return a[..., None] * tint


def response(kind: str, linear: np.ndarray) -> np.ndarray:
    """Camera response: linear radiance (1 = white projector on a white wall) -> 0..255."""
    if kind == "gamma":
        out = np.clip(linear, 0, 1) ** (1 / 2.2)
    elif kind == "s-curve":
        out = 1 / (1 + np.exp(-6 * (np.clip(linear, 0, 1.2) ** 0.6 - 0.5)))
        out = (out - out.min()) / max(float(out.max() - out.min()), 1e-6)
    elif kind == "linear":
        out = np.clip(1.3 * linear, 0, 1)  # over-exposed: highlights clip
    else:
        raise ValueError(kind)
    return 255 * out


def render(name: str, projected: np.ndarray, index: int, seed: int, force: dict | None = None) -> Pair:
    """Render ``projected`` through the rig number ``index`` (settings rotate with it, jitter from ``seed``;
    ``force`` fixes some: keys ``shape``, ``albedo``, ``response``, ``ambient``)."""
    h, w = projected.shape[:2]
    rng = np.random.default_rng([seed, index])
    settings = {
        "shape": SHAPES[index % 4],
        "albedo": ALBEDOS[(index // 2) % 4],
        "response": RESPONSES[index % 3],
        "ambient": AMBIENTS[(index // 3) % 4],
        **(force or {}),
    }
    shape, wall, resp, ambient = settings.values()
    H, bend = random_homography(rng, h, w), surface_map(shape, rng, h, w)

    def forward(p):
        return bend(apply_h(H, p))

    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    grid = np.stack([x, y], axis=-1)
    fwd = forward(grid)
    src = invert(forward, grid, apply_h(np.linalg.inv(H), grid)).astype(np.float32)  # camera -> projector
    lit = (src[..., 0] >= 0) & (src[..., 0] <= w - 1) & (src[..., 1] >= 0) & (src[..., 1] <= h - 1)
    light = (projected.astype(np.float32) / 255) ** 2.2
    mix = np.eye(3, dtype=np.float32) * 0.85 + 0.05 + rng.uniform(-0.03, 0.03, (3, 3)).astype(np.float32)
    light = cv2.remap(light @ mix.T, src[..., 0], src[..., 1], cv2.INTER_LINEAR) * lit[..., None]
    vignette = (1 - 0.35 * (((grid - [w / 2, h / 2]) / max(h, w)) ** 2).sum(axis=-1))[..., None]
    radiance = albedo(wall, rng, h, w) * (0.9 * light + ambient) * vignette.astype(np.float32)
    radiance = cv2.GaussianBlur(radiance, (0, 0), rng.uniform(0.5, 1.2))
    cap = response(resp, radiance) + rng.normal(0, rng.uniform(1.0, 3.0), radiance.shape)
    valid = (fwd[..., 0] >= 0) & (fwd[..., 0] <= w - 1) & (fwd[..., 1] >= 0) & (fwd[..., 1] <= h - 1)
    flow = (fwd - grid).astype(np.float32)
    return Pair(name, projected, np.clip(cap, 0, 255).astype(np.uint8), flow, valid, settings)


def contents(h: int, w: int) -> list[tuple[str, np.ndarray]]:
    """The projected pictures: every picture full frame, three on one side only, one almost blank."""
    out = [(n, picture(n, h, w)) for n in PICTURES]
    for n in ONE_SIDED:
        half = picture(n, h, w)
        half[:, int(0.45 * w) :] = (120, 128, 140)
        out.append((f"{n}-left", half))
    blank = np.full((h, w, 3), 150, np.uint8)
    cv2.putText(blank, "page 3", (w // 10, h // 6), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (143, 143, 143), 1)
    out.append(("blank", blank))
    return out


def write_pairs(pairs: list[Pair], out: Path) -> None:
    for sub in ("projected", "captured"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for p in pairs:
        for sub, img in (("projected", p.projected), ("captured", p.captured)):
            if not cv2.imwrite(str(out / sub / f"{p.name}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
                raise SystemExit(f"external_rig: cannot write {out / sub / p.name}.png")


def run_predict(out: Path, extra: list[str]) -> float:
    """``projreg predict`` on the folders, as a user runs it; returns its wall time in seconds."""
    exe = Path(sys.executable).with_name("projreg")
    cmd = [
        str(exe),
        "predict",
        "--projected",
        str(out / "projected"),
        "--captured",
        str(out / "captured"),
        "--out",
        str(out / "flow"),
        "--quiet",
        *extra,
    ]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stderr=subprocess.PIPE, text=True)
    return time.perf_counter() - t0


def epe(flow: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float | None:
    return float(np.linalg.norm(flow - truth, axis=-1)[mask].mean()) if mask.any() else None


def score(pair: Pair, out: Path, baselines: dict) -> dict:
    """Issue 16's per-pair figures for one pair (module docstring)."""
    from projsynth.flow.formats import read_flow_exr

    flow, claimed, header = read_flow_exr(out / "flow" / f"{pair.name}_flow.exr")
    v = pair.valid
    vc = v & claimed.astype(bool)
    row = {
        "pair": pair.name,
        **pair.settings,
        "registered": header.get("registered", "yes") == "yes",
        "claimed": float(vc.sum() / max(v.sum(), 1)),
        "epe_claimed": epe(flow, pair.flow, vc),
        "epe": epe(flow, pair.flow, v),
        "zero_flow": epe(0 * flow, pair.flow, v),
    }
    for name, method in baselines.items():
        start = time.perf_counter()
        f = method.predict(pair.projected, pair.captured)
        row[f"{name}_seconds"] = time.perf_counter() - start
        row[name] = epe(f, pair.flow, v)
        row[f"{name}_on_claimed"] = epe(f, pair.flow, vc)
    on_claimed = [row[f"{n}_on_claimed"] for n in baselines if row[f"{n}_on_claimed"] is not None]
    row["best_baseline"] = min(row[n] for n in baselines)
    row["ratio"] = None if row["epe_claimed"] is None else row["epe_claimed"] / max(min(on_claimed), 1e-3)
    return row


def summary(rows: list[dict]) -> dict:
    rated = [r for r in rows if r["ratio"] is not None]
    worst = max(rated, key=lambda r: r["ratio"]) if rated else None
    return {
        "pairs": len(rows),
        "rated": len(rated),
        "within_1_5": sum(r["ratio"] <= 1.5 for r in rated) / max(len(rated), 1),
        "worst_ratio": worst and worst["ratio"],
        "worst_pair": worst and worst["pair"],
        "claimed_mean": float(np.mean([r["claimed"] for r in rows])),
        "epe_mean": float(np.mean([r["epe"] for r in rows])),
        "best_baseline_mean": float(np.mean([r["best_baseline"] for r in rows])),
        "not_registered": [r["pair"] for r in rows if not r["registered"]],
        "baseline_seconds": {k[: -len("_seconds")]: sum(r[k] for r in rows) for k in rows[0] if k.endswith("_seconds")},
    }


def markdown(rows: list[dict], total: dict, names: list[str]) -> str:
    def f(x, fmt=".2f"):
        return "–" if x is None else format(x, fmt)

    head = ["pair", "shape", "albedo", "response", "ambient", "claimed %", "EPE claimed", "EPE all"]
    lines = ["| " + " | ".join(head + [*names, "ratio"]) + " |", "|" + "---|" * (len(head) + len(names) + 1)]
    for r in rows:
        cells = [
            r["pair"] + ("" if r["registered"] else " (not registered)"),
            r["shape"],
            r["albedo"],
            r["response"],
            f(r["ambient"]),
            f(100 * r["claimed"], ".1f"),
            f(r["epe_claimed"]),
            f(r["epe"]),
            *(f"{f(r[n])} ({f(r[n + '_on_claimed'])})" for n in names),
            f(r["ratio"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        f"{total['rated']} of {total['pairs']} pairs rated; within 1.5x: {100 * total['within_1_5']:.0f} %; "
        f"worst ratio {f(total['worst_ratio'])} ({total['worst_pair']}); claimed {100 * total['claimed_mean']:.1f} % "
        f"on average; mean per-pair EPE {total['epe_mean']:.2f} px against the best baseline's "
        f"{total['best_baseline_mean']:.2f}; not registered: {', '.join(total['not_registered']) or 'none'}"
    )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("build/external"))
    ap.add_argument("--size", default="384x512", help="H x W of every pair")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--limit", type=int, default=0, help="only the first N pairs (0: all)")
    ap.add_argument("--predict-args", default="", help="extra options for projreg predict, e.g. '--fast'")
    ap.add_argument("--shape", choices=SHAPES + MORE_SHAPES, help="every pair on this surface (default: they rotate)")
    ap.add_argument("--albedo", choices=ALBEDOS + MORE_ALBEDOS, help="every pair on this wall (default: they rotate)")
    ap.add_argument("--response", choices=RESPONSES, help="every pair through this camera response")
    ap.add_argument("--ambient", type=float, help="every pair under this ambient light (0: dark room)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--markdown", type=Path)
    args = ap.parse_args()
    from projreg.evaluation.baselines import make_baseline

    h, w = (int(v) for v in args.size.lower().split("x"))
    items = contents(h, w)[: args.limit or None]
    force = {k: getattr(args, k) for k in ("shape", "albedo", "response", "ambient") if getattr(args, k) is not None}
    pairs = [render(name, img, i, args.seed, force) for i, (name, img) in enumerate(items)]
    write_pairs(pairs, args.out)
    seconds = run_predict(args.out, args.predict_args.split())
    names = ["sift-ransac", "dis-medium"]
    baselines = {n: make_baseline(n) for n in names}
    rows = [score(p, args.out, baselines) for p in pairs]
    total = {**summary(rows), "predict_seconds": seconds, "size": args.size, "seed": args.seed, "force": force}
    text = markdown(rows, total, names)
    print(text, end="")
    if args.json:
        args.json.write_text(json.dumps({"summary": total, "pairs": rows}, indent=1))
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()
