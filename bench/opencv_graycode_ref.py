"""OpenCV's own Gray-code decoder against ``projsynth decode --layout opencv``, on photos with an exact truth.

Usage: python bench/opencv_graycode_ref.py --opencv-python PYTHON [--sizes 96x128,240x320,480x640]
    [--cases noise-free,clipped,perfect] [--keep DIR] [--json F]

OpenCV's decoder is in its contrib modules (``cv2.structured_light``), which projsynth does not depend on: the
``opencv-contrib-python-headless`` wheel installs its own ``cv2`` over ``opencv-python-headless``'s. Put it in
an environment of its own and name that interpreter with ``--opencv-python``::

    python3 -m venv /tmp/cvref && /tmp/cvref/bin/pip install numpy opencv-contrib-python-headless
    python bench/opencv_graycode_ref.py --opencv-python /tmp/cvref/bin/python

(run from a checkout, in projsynth's environment; without ``--opencv-python`` this interpreter must have the
contrib modules itself). Per projector size and case:

1. OpenCV generates its patterns (``GrayCodePattern.generate``, then ``getImagesForShadowMasks``' white and
   black, in its capture sample's order); the script checks they are projsynth's ``opencv-graycode`` set.
2. They are photographed through the analytic scene of ``tests/projsynth/structured/test_opencv_captures.py``
   (a homography and a smooth bend, camera 1.25x the projector, albedo, defocus, a 1/2.2 response, no
   noise, black exactly 0): ``noise-free`` (the brightest white at 95 % of full scale) and ``clipped`` (the
   white of a sixth of the lit pixels clipped at 255); ``perfect`` is the patterns themselves as the photos
   (camera = projector grid). The photos go into one folder, named as OpenCV's capture sample names them.
3. OpenCV decodes them. Its ``decode`` is the stereo path (two cameras' pixels paired into a disparity map;
   no projector position comes out of it): it keeps the camera pixels whose white - black exceeds the black
   threshold (its shadow mask) and gives each the projector pixel ``getProjPixel`` decodes, unless a bit's
   pattern and inverse differ by less than the white threshold. For one camera this script takes the same
   two steps, thresholds at OpenCV's defaults (40 and 5), ``getProjPixel`` called on every masked pixel.
4. ``projsynth decode --layout opencv --projector HxW`` decodes the same folder, in its own process (a
   warning it prints is reported).

Coverage: the share of the projector pixels whose true camera position lies in the camera frame that get a
correspondence (ours: valid in ``correspondence.exr``; OpenCV's: hit by at least one camera pixel it keeps).
Error: camera px against the analytic truth; OpenCV's at a projector pixel is the mean position of the camera
pixels that decode to it (how its ``decode`` pools them), ours the decoded position. ``both`` compares the
two where both decode; ``all`` each over everything it decodes.
"""

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "projsynth" / "structured" / "test_opencv_captures.py"
BLACK_THRESHOLD, WHITE_THRESHOLD = 40, 5  # GrayCodePattern's defaults, 8-bit DN
CASES = ("noise-free", "clipped", "perfect")
PHOTO = "pattern_cam1_im{}.png"  # OpenCV's capture sample's names, numbered from 1
MISSING = (
    "cv2.structured_light is missing: OpenCV's decoder is in its contrib modules. Install them apart from "
    "projsynth (python3 -m venv /tmp/cvref && /tmp/cvref/bin/pip install numpy opencv-contrib-python-headless) "
    "and pass --opencv-python /tmp/cvref/bin/python"
)


# --- OpenCV's side: runs in an interpreter with the contrib modules (numpy and cv2 only) -------------------


def opencv_patterns(size: tuple[int, int]) -> np.ndarray:
    """``(N, H, W)`` uint8: OpenCV's patterns for an ``H x W`` projector, then white, then black."""
    h, w = size
    graycode = cv2.structured_light.GrayCodePattern.create(w, h)
    _, patterns = graycode.generate()
    black, white = graycode.getImagesForShadowMasks(np.zeros((h, w), np.uint8), np.zeros((h, w), np.uint8))
    return np.stack([*patterns, white, black])


def opencv_decode(folder: Path, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The projector ``(x, y)`` OpenCV gives each camera pixel of the photos in ``folder``, ``(Hc, Wc)`` int64
    each, -1 where it keeps none (module docstring, step 3)."""
    h, w = size
    graycode = cv2.structured_light.GrayCodePattern.create(w, h)
    graycode.setBlackThreshold(BLACK_THRESHOLD)
    graycode.setWhiteThreshold(WHITE_THRESHOLD)
    count = graycode.getNumberOfPatternImages()
    photos = [cv2.imread(str(folder / PHOTO.format(i + 1)), cv2.IMREAD_GRAYSCALE) for i in range(count + 2)]
    patterns, white, black = photos[:count], photos[count], photos[count + 1]
    x = np.full(white.shape, -1, np.int64)
    y = np.full(white.shape, -1, np.int64)
    for cy, cx in zip(*np.nonzero(white.astype(np.int64) - black > BLACK_THRESHOLD), strict=True):
        error, (px, py) = graycode.getProjPixel(patterns, int(cx), int(cy))
        if not error:
            x[cy, cx], y[cy, cx] = px, py
    return x, y


def opencv_step(args: argparse.Namespace) -> None:
    """``--opencv-step``: one of OpenCV's steps, its result saved to ``--step-out`` (.npy)."""
    if not hasattr(cv2, "structured_light"):
        sys.exit(MISSING)
    size = parse_size(args.size)
    if args.opencv_step == "patterns":
        np.save(args.step_out, opencv_patterns(size))
    else:
        np.save(args.step_out, np.stack(opencv_decode(Path(args.photos), size)))


# --- projsynth's side --------------------------------------------------------------------------------------


def parse_size(text: str) -> tuple[int, int]:
    h, w = (int(v) for v in text.lower().split("x"))
    return h, w


def run_opencv(python: str | None, step: str, size: tuple[int, int], work: Path, photos: Path | None = None):
    """One of OpenCV's steps, in this interpreter if it has the contrib modules, else in ``python``."""
    if python is None:
        if not hasattr(cv2, "structured_light"):
            sys.exit(MISSING)
        return opencv_patterns(size) if step == "patterns" else np.stack(opencv_decode(photos, size))
    out = work / f"opencv-{step}.npy"
    command = [python, __file__, "--opencv-step", step, "--size", f"{size[0]}x{size[1]}", "--step-out", str(out)]
    done = subprocess.run(command + (["--photos", str(photos)] if photos else []), capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(done.stderr.strip() or f"{python}: OpenCV's step {step} failed")
    return np.load(out)


def opencv_version(python: str | None) -> str:
    if python is None:
        return cv2.__version__
    done = subprocess.run([python, "-c", "import cv2; print(cv2.__version__)"], capture_output=True, text=True)
    return done.stdout.strip()


def load_scene():
    """The analytic scene of the test suite (module docstring, step 2), loaded by path: tests are no package."""
    spec = importlib.util.spec_from_file_location("opencv_captures", SCENE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def pooled(x: np.ndarray, y: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's projector -> camera map: each projector pixel at the mean position of the camera pixels that
    decode to it; ``(position (H, W, 2), hit (H, W))``."""
    h, w = size
    ok = x >= 0
    qy, qx = np.mgrid[0 : x.shape[0], 0 : x.shape[1]]
    index = (y * w + x)[ok]
    n = np.bincount(index, minlength=h * w).reshape(h, w)
    mean = [np.bincount(index, q[ok], h * w).reshape(h, w) / np.maximum(n, 1) for q in (qx, qy)]
    return np.stack(mean, -1), n > 0


def ours(folder: Path, size: tuple[int, int], out: Path) -> tuple[np.ndarray, np.ndarray, dict, str]:
    """``projsynth decode --layout opencv`` of ``folder``: ``(position (H, W, 2), valid, decode.json, printed)``,
    ``printed`` what it wrote besides its one summary line (nothing, or an error or warnings)."""
    from projsynth.flow.formats import read_flow_exr

    main = "import sys; from projsynth.cli import main; sys.argv[0] = 'projsynth'; main()"
    command = [sys.executable, "-c", main, "decode", "--layout", "opencv", "--projector", f"{size[0]}x{size[1]}"]
    done = subprocess.run([*command, "--captures", str(folder), "--out", str(out)], capture_output=True, text=True)
    printed = " / ".join(line for line in done.stderr.splitlines() if line.strip() and not line.startswith(f"{out}: "))
    if done.returncode != 0:
        return np.zeros((*size, 2)), np.zeros(size, bool), {}, printed
    flow, valid, _ = read_flow_exr(out / "correspondence.exr")
    ys, xs = np.mgrid[0 : size[0], 0 : size[1]]
    return flow + np.stack([xs, ys], -1), valid, json.loads((out / "decode.json").read_text()), printed


def summary(err: np.ndarray) -> dict:
    if not err.size:
        return {"mean": None, "p99": None, "max": None}
    return {"mean": float(err.mean()), "p99": float(np.percentile(err, 99)), "max": float(err.max())}


def measure(case: str, size: tuple[int, int], patterns: np.ndarray, python: str | None, work: Path) -> dict:
    scene = load_scene()
    if case == "perfect":
        camera, photos = size, patterns
        ys, xs = np.mgrid[0 : size[0], 0 : size[1]]
        truth = np.stack([xs, ys], -1).astype(np.float64)
    else:
        camera = scene.CAMERAS[size]
        photos = scene.noise_free_photos(list(patterns), camera, clipped=case == "clipped")
        truth = scene.true_forward(size)
    folder = work / f"{case}-{size[0]}x{size[1]}"
    folder.mkdir(parents=True)
    for i, photo in enumerate(photos):
        cv2.imwrite(str(folder / PHOTO.format(i + 1)), photo)
    x, y = run_opencv(python, "decode", size, work, folder)
    cv_pos, hit = pooled(x, y, size)
    our_pos, valid, record, printed = ours(folder, size, work / f"out-{case}-{size[0]}x{size[1]}")
    inside = scene.in_frame(truth, camera)
    both = hit & valid & inside
    lit = photos[-2] > 0
    clipped = None if case == "perfect" else float((photos[-2][lit] == 255).mean())
    return {
        "case": case,
        "size": f"{size[0]}x{size[1]}",
        "camera": f"{camera[0]}x{camera[1]}",
        "clipped_share": clipped,
        "coverage_opencv": float((hit & inside).sum() / inside.sum()),
        "coverage_ours": float((valid & inside).sum() / inside.sum()),
        "both_opencv": summary(np.hypot(*(cv_pos - truth)[both].T)),
        "both_ours": summary(np.hypot(*(our_pos - truth)[both].T)),
        "all_opencv": summary(np.hypot(*(cv_pos - truth)[hit & inside].T)),
        "all_ours": summary(np.hypot(*(our_pos - truth)[valid].T)),
        "diff_noise_dn": record.get("diff_noise_dn"),
        "printed": printed,
    }


def row(r: dict) -> str:
    def fig(s: dict) -> str:
        return "-" if s["mean"] is None else f"{s['mean']:.3f} / {s['p99']:.3f} / {s['max']:.3f}"

    clipped = "" if r["clipped_share"] is None else f" ({r['clipped_share']:.0%} clipped)"
    return (
        f"| {r['size']} ({r['camera']}) | {r['case']}{clipped} | "
        f"{r['coverage_opencv']:.2%} | {r['coverage_ours']:.2%} | {fig(r['both_opencv'])} | {fig(r['both_ours'])} | "
        f"{fig(r['all_opencv'])} | {fig(r['all_ours'])} | {r['diff_noise_dn']} | {r['printed'] or 'nothing'} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--opencv-python", help="an interpreter with cv2.structured_light (default: this one)")
    ap.add_argument("--sizes", default="96x128,240x320,480x640", help="projector sizes HxW, comma-separated")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--keep", type=Path, help="keep the photos and both decodes in this new folder")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON to this file")
    ap.add_argument("--opencv-step", choices=("patterns", "decode"), help=argparse.SUPPRESS)
    ap.add_argument("--size", help=argparse.SUPPRESS)
    ap.add_argument("--photos", help=argparse.SUPPRESS)
    ap.add_argument("--step-out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.opencv_step:
        return opencv_step(args)
    from projsynth.structured.patterns import opencv_set

    cases = args.cases.split(",")
    if unknown := set(cases) - set(CASES):
        ap.error(f"--cases: {', '.join(sorted(unknown))} is not one of {', '.join(CASES)}")
    if args.keep:
        args.keep.mkdir(parents=True)
    work = args.keep or Path(tempfile.mkdtemp(prefix="opencv-graycode-ref-"))
    results = []
    try:
        for size in map(parse_size, args.sizes.split(",")):
            patterns = run_opencv(args.opencv_python, "patterns", size, work)
            if not np.array_equal(patterns, np.stack(opencv_set(size).images())):
                sys.exit(f"{size[0]}x{size[1]}: OpenCV's patterns are not projsynth's opencv-graycode set")
            results += [measure(case, size, patterns, args.opencv_python, work) for case in cases]
    finally:
        if not args.keep:
            shutil.rmtree(work)
    version = opencv_version(args.opencv_python)
    print(f"OpenCV {version}'s decoder against projsynth's; errors: camera px, mean / p99 / max\n")
    print(
        "| projector (camera) | case | coverage OpenCV | coverage ours | both: OpenCV | both: ours | all: OpenCV "
        "| all: ours | diff_noise_dn | decode printed besides its summary |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(row(r) for r in results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
