"""Warp export against ``projreg compensate`` (issue 58): the STMap, the meshes and the ``cv2.remap`` maps
of ``projreg warp``, applied as show software applies them, beside ``compensate``'s image of the same flow.

Usage: python bench/bench_warp.py --data DIR [--limit N] [--steps 8,16,32] [--out FILE.json]

For each pair of a ``projsynth gen`` dataset (``--limit``: that many, spread evenly): ``projreg predict``
(the shipped model, default options) writes its flow EXR; the picture to show is the pair's projected
image (it spans the camera frame, of the same size here); ``projreg compensate`` pre-warps it, twice,
with ``--fill 0`` and ``--fill 255``, so that the pixels where it shows content are those where the two
agree (read off its images, not off the code under test). Then ``projreg warp`` writes each file, and
each is read back and applied as a show tool applies it:

* the STMap (``.exr``): ``cv2.remap`` at ``x = u W - 0.5``, ``y = (1 - v) H - 0.5``, bilinear, border
  replicated, content where A = 1;
* each mesh (``.obj``, ``--steps``): rasterised here as a renderer draws it (every triangle filled with
  its index by ``cv2.fillConvexPoly``, texture coordinates linear over the triangle at each pixel
  centre), then remapped as the STMap;
* the ``.npz``: ``cv2.remap(content, map_x, map_y, cv2.INTER_LINEAR)``, as docs/show.md writes it.

Per file: the mean and the largest absolute difference from ``compensate``'s image in grey levels
(0..255, over the three channels) on the pixels where both show content, ``covered`` (the share of
compensate's pixels with content that the file shows content on), ``beyond`` (pixels it shows content
on that compensate does not), the file's size and, for the meshes, ``projreg warp``'s reported
interpolation error (camera pixels). The table pools the pairs: the mean of the per-pair means and
shares, the largest maximum, the sum of ``beyond``, the median size.

``--out`` writes the JSON: ``command``, ``data``, ``date``, ``pairs`` (the per-pair figures: ``id``,
``registered``, then one object per file kind, keyed ``stmap``, ``npz``, ``mesh8``...), ``rows`` (the
table's rows: ``file``, ``grey_mean``, ``grey_max``, ``covered``, ``beyond``, ``kib_median``, and for
the meshes ``error_mean_px``, ``error_max_px``), ``flow_kib_median``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import OpenEXR

from projreg.evaluation.metrics import sample_indices
from projreg.inference.compensate import compensate_files
from projreg.inference.predict import predict
from projreg.inference.warpfiles import export_warp_file
from projsynth.api import open_dataset


def write_rgb(path: Path, image: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def read_rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def read_stmap(path: Path) -> np.ndarray:
    channels = OpenEXR.File(str(path), separate_channels=True).channels()
    return np.stack([channels[c].pixels for c in "RGBA"], -1)  # [H, W, 4]


def render_obj(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The OBJ's texture coordinates at every projector pixel a triangle covers, RGBA as an STMap
    (A = 1 there): each triangle filled with its index, then barycentric weights at the pixel centres."""
    lines = path.read_text().splitlines()
    v = np.array([ln.split()[1:3] for ln in lines if ln.startswith("v ")], np.float64)
    vt = np.array([ln.split()[1:3] for ln in lines if ln.startswith("vt ")], np.float64)
    tri = np.array([[int(c.split("/")[0]) - 1 for c in ln.split()[1:]] for ln in lines if ln.startswith("f ")])
    ids = np.full(shape, -1, np.int32)
    for k, t in enumerate(tri):
        cv2.fillConvexPoly(ids, np.rint(v[t]).astype(np.int32), int(k))
    py, px = np.nonzero(ids >= 0)
    t = tri[ids[py, px]]  # [N, 3]
    (x0, y0), (x1, y1), (x2, y2) = (v[t[:, i]].T for i in range(3))
    det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
    a = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / det
    b = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / det
    rgba = np.zeros((*shape, 4), np.float32)
    rgba[..., :2] = -1.0
    rgba[py, px, :2] = a[:, None] * vt[t[:, 0]] + b[:, None] * vt[t[:, 1]] + (1 - a - b)[:, None] * vt[t[:, 2]]
    rgba[py, px, 3] = 1
    return rgba


def through_stmap(content: np.ndarray, rgba: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The content remapped through an STMap (bilinear, border replicated), and where A = 1."""
    h, w = content.shape[:2]
    x, y = rgba[..., 0] * w - 0.5, (1 - rgba[..., 1]) * h - 0.5
    return cv2.remap(content, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), rgba[..., 3] == 1


def compare(image: np.ndarray, shown: np.ndarray, want: np.ndarray, want_shown: np.ndarray) -> dict:
    both = shown & want_shown
    diff = np.abs(image.astype(np.int16) - want)[both]
    return {
        "grey_mean": float(diff.mean()),
        "grey_max": int(diff.max()),
        "covered": float(both.sum() / want_shown.sum()),
        "beyond": int((shown & ~want_shown).sum()),
    }


def bench_pair(sample: dict, work: Path, flow: Path, steps: list[int]) -> dict:
    content = sample["projected"]  # spans the camera frame (of the projector's size in these datasets)
    write_rgb(work / "content.png", content)
    runs = [compensate_files(work / "content.png", flow, work / f"comp{fill}.png", fill) for fill in (0, 255)]
    dark, light = read_rgb(work / "comp0.png"), read_rgb(work / "comp255.png")
    want_shown = (dark == light).all(axis=2)
    shape = dark.shape[:2]
    out = {"id": sample["params"]["sample_id"], "registered": runs[0]["registered"], "shown": float(want_shown.mean())}
    export_warp_file(flow, work / "w.exr")
    out["stmap"] = compare(*through_stmap(content, read_stmap(work / "w.exr")), dark, want_shown)
    out["stmap"]["kib"] = (work / "w.exr").stat().st_size / 1024
    export_warp_file(flow, work / "w.npz")
    m = np.load(work / "w.npz")
    remapped = cv2.remap(content, m["map_x"], m["map_y"], cv2.INTER_LINEAR)
    out["npz"] = compare(remapped, m["shown"], dark, want_shown) | {"kib": (work / "w.npz").stat().st_size / 1024}
    for step in steps:
        reported = export_warp_file(flow, work / "w.obj", step=step)
        drawn = compare(*through_stmap(content, render_obj(work / "w.obj", shape)), dark, want_shown)
        out[f"mesh{step}"] = drawn | {
            "error_mean_px": reported["error_mean"],
            "error_max_px": reported["error_max"],
            "kib": (work / "w.obj").stat().st_size / 1024,
        }
    return out


def table(pairs: list[dict], steps: list[int]) -> list[dict]:
    rows = []
    for key, name in [("stmap", "STMap .exr"), *((f"mesh{s}", f"mesh .obj, step {s}") for s in steps), ("npz", ".npz")]:
        runs = [p[key] for p in pairs]
        row = {
            "file": name,
            "grey_mean": statistics.mean(r["grey_mean"] for r in runs),
            "grey_max": max(r["grey_max"] for r in runs),
            "covered": statistics.mean(r["covered"] for r in runs),
            "beyond": sum(r["beyond"] for r in runs),
            "kib_median": statistics.median(r["kib"] for r in runs),
        }
        if key.startswith("mesh"):
            row["error_mean_px"] = statistics.mean(r["error_mean_px"] for r in runs)
            row["error_max_px"] = max(r["error_max_px"] for r in runs)
        rows.append(row)
    return rows


def markdown(rows: list[dict], n: int, flow_kib: float) -> str:
    lines = [
        f"{n} pairs; grey levels 0..255 where both show content; flow EXR {flow_kib:.0f} KiB (median)",
        "",
        "| file | grey mean | grey max | covered | shown beyond | mesh error mean / max (camera px) | KiB |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        error = f"{r['error_mean_px']:.3f} / {r['error_max_px']:.3f}" if "error_mean_px" in r else "–"
        lines.append(
            f"| {r['file']} | {r['grey_mean']:.3f} | {r['grey_max']} | {r['covered']:.2%} | {r['beyond']} | {error} | "
            f"{r['kib_median']:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a projsynth gen dataset")
    parser.add_argument("--limit", type=int, default=None, help="this many pairs, spread evenly (default: all)")
    parser.add_argument("--steps", default="8,16,32", help="mesh steps, comma-separated")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args()
    steps = [int(s) for s in args.steps.split(",")]
    with open_dataset(args.data) as ds, tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        picked = [ds[i] for i in sample_indices(len(ds), args.limit)]
        for folder in ("projected", "captured"):
            (work / folder).mkdir()
            for s in picked:
                write_rgb(work / folder / f"{s['params']['sample_id']}.png", s[folder])
        predict(work / "projected", work / "captured", work / "flows")
        pairs, flow_kib = [], []
        for s in picked:
            flow = work / "flows" / f"{s['params']['sample_id']}_flow.exr"
            flow_kib.append(flow.stat().st_size / 1024)
            pairs.append(bench_pair(s, work, flow, steps))
    rows = table(pairs, steps)
    print(markdown(rows, len(pairs), statistics.median(flow_kib)))
    if args.out is not None:
        report = {
            "command": " ".join(["python", *sys.argv]),
            "data": str(args.data),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "pairs": pairs,
            "rows": rows,
            "flow_kib_median": statistics.median(flow_kib),
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
