"""The devices' response fitted on the virtual rig, against the simulator's known curves (docs/real-rig.md, 9).

Usage: python bench/bench_response.py [--size 192x256] [--seed 3] [--figure docs/img/response-curves.png]

One planar scene of each photometric condition (transforms 0-4: studio, night, daylight, translucent,
noisy), twice: as the built-in table draws it (its transparency field varies by 10% at most, so the
room's light is in nearly one proportion to the projector's everywhere), and with the room's light
varying against the projector's (the transparency field spanning 0.05-0.95 under a room light of 0.1).
The 17 grey levels of ``projsynth patterns --kind response`` are photographed through each
(``projsynth.structured.capture``: every photo its own noise) and fitted. One Markdown row per scene:
the simulated camera's exponent (the projector's gamma is 2.2), the fitted one with the range the photos
allow and whether it is identified, the max / mean absolute error over code values 0..255 of the
normalised camera curve ``c^exponent`` and of the projector's curves, and the worst bias (DN, over the
interior levels, mean over lit unclipped pixels) of a level's photo predicted from the black and white
photos, with the fitted curves and with gamma 2.2 for both devices. ``--figure`` draws the curves of the
studio scene, both ways, against the truth.
"""

import argparse
from dataclasses import replace

import cv2
import numpy as np

from projsynth.dataset.plan import parse_size
from projsynth.dataset.transforms import TransformTable, builtin_table
from projsynth.structured.capture import make_rig, shoot
from projsynth.structured.patterns import make_set
from projsynth.structured.response import Response, fit_response

CODES = np.arange(256) / 255
CONDITIONS = (0, 1, 2, 3, 4)


def varying(table: TransformTable) -> TransformTable:
    """``table`` with the room's light varying against the projector's in the scenes of ``CONDITIONS``."""
    configs = list(table.configs)
    for t in CONDITIONS:
        light = {**configs[t].photometry, "alpha": (0.5, 0.5), "alpha_var": (0.45, 0.45), "ambient": (0.1, 0.1)}
        configs[t] = replace(configs[t], photometry=light)
    return TransformTable("room light varies", tuple(configs))


def measure(table: TransformTable, tid: int, size: tuple[int, int], seed: int) -> tuple[dict, Response, float]:
    steps = make_set("response", size)
    levels = steps.params["levels"]
    rig = make_rig(table, tid, seed, size, size)
    photos = np.stack([shoot(rig, img, seed, i) for i, img in enumerate(steps.images())])
    fitted = fit_response(levels, photos.astype(np.float32) / 255)
    truth = rig.photometry["response"]
    lit = ((photos[-1].astype(int) - photos[0]).min(axis=2) > 13) & (photos[-1] < 250).all(axis=2)

    def bias(curves: Response) -> float:
        inner = enumerate(levels[1:-1], start=1)
        return max(abs(float((curves.predict(photos[0], photos[-1], v) - photos[k])[lit].mean())) for k, v in inner)

    camera = np.abs(CODES**fitted.camera_exponent - CODES**truth)
    projector = np.abs(fitted.projector - CODES**2.2)
    row = {
        "condition": table.configs[tid].condition,
        "truth": truth,
        "exponent": fitted.camera_exponent,
        "interval": fitted.interval,
        "identified": fitted.identified,
        "camera": (camera.max(), camera.mean()),
        "projector": (projector.max(), projector.mean()),
        "bias": (bias(fitted), bias(Response.from_gamma(2.2))),
        "rms": fitted.rms_dn,
    }
    return row, fitted, truth


def draw(curves: list[tuple[str, Response, float]], path: str) -> None:
    """Two panels (camera ``F^-1``, projector ``g``; code value 0..255 -> 0..1): truth in grey, fits in colour."""
    w, h, pad = 360, 300, 40
    sheet = np.full((h + 2 * pad, 2 * (w + 2 * pad), 3), 255, np.uint8)
    colours = [(200, 80, 0), (0, 120, 230)]  # BGR
    labels = [*(label for label, _, _ in curves), "grey: the simulator's curves (green channel shown)"]
    font = cv2.FONT_HERSHEY_SIMPLEX
    for panel, title in enumerate(("camera: value -> linear light", "projector: code value -> light")):
        x0 = panel * (w + 2 * pad) + pad
        cv2.rectangle(sheet, (x0, pad), (x0 + w, pad + h), (0, 0, 0), 1)
        cv2.putText(sheet, title, (x0, pad - 12), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        for text, x in (("0", x0), ("255", x0 + w - 20)):
            cv2.putText(sheet, text, (x, pad + h + 16), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        for (_, fitted, truth), colour in zip(curves, colours, strict=True):
            exact = CODES ** (truth if panel == 0 else 2.2)
            fit = CODES**fitted.camera_exponent if panel == 0 else fitted.projector[1]
            for ys, c, t in ((exact, (150, 150, 150), 3), (fit, colour, 1)):
                pts = np.stack([x0 + CODES * w, pad + h - ys * h], axis=1).round().astype(np.int32)
                cv2.polylines(sheet, [pts], False, c, t, cv2.LINE_AA)
    for i, (text, colour) in enumerate(zip(labels, [*colours, (120, 120, 120)], strict=True)):
        cv2.putText(sheet, text, (pad + 8, pad + 20 + 16 * i), font, 0.38, colour, 1, cv2.LINE_AA)
    cv2.imwrite(path, sheet)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="192x256")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--figure", default=None, help="PNG of the studio scene's curves")
    args = parser.parse_args()
    size = parse_size(args.size)
    print(
        "| scene | condition | camera exponent: true / fitted (range) | identified | camera curve err max / mean "
        "| projector curve err max / mean | worst level bias DN: fitted / gamma 2.2 | residual DN |"
    )
    print("|---|---|---|---|---|---|---|---|")
    studio = []
    for name, table in (("built-in", builtin_table()), ("room light varies", varying(builtin_table()))):
        for tid in CONDITIONS:
            r, fitted, truth = measure(table, tid, size, args.seed)
            lo, hi = r["interval"]
            print(
                f"| {name} | {r['condition']} | {r['truth']:.2f} / {r['exponent']:.2f} ({lo:.2f}-{hi:.2f}) | "
                f"{'yes' if r['identified'] else 'no'} | {r['camera'][0]:.3f} / {r['camera'][1]:.4f} | "
                f"{r['projector'][0]:.3f} / {r['projector'][1]:.4f} | {r['bias'][0]:.2f} / {r['bias'][1]:.2f} | "
                f"{r['rms']:.2f} |"
            )
            if tid == 0:
                how = "" if fitted.identified else ", assumed"
                studio.append((f"{name}: exponent {fitted.camera_exponent:.2f}{how} (true {truth:.2f})", fitted, truth))
    if args.figure:
        draw(studio, args.figure)


if __name__ == "__main__":
    main()
