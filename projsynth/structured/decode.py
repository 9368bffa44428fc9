"""Decode photos of a pattern set into the projector -> camera correspondence (structured light).

The result is a flow on the **projector grid** in **camera pixels**, exactly as the shards store
ground truth: projector pixel ``(x, y)`` is seen at camera pixel ``(x + u, y + v)`` of the photos.
``valid`` only where the decode is trustworthy.

``graycode`` (dense, sub-pixel), in two steps:

1. Per camera pixel, the projector position it sees: Gray code (each bit against its inverse, so
   ambient light, albedo and gamma cancel) gives the stripe, the phase of ``N`` shifted fringes the
   position inside the fringe period (``atan2`` of the first Fourier coefficient: an offset, a gain and
   any harmonic below order ``N - 1`` of the projector's gamma or the camera's response cancel).
   A pixel is kept when the white-black contrast and the fringe modulation are high enough, no fringe
   photo is saturated, and the unwrapped phase agrees with its stripe.
2. Per projector pixel, the camera position: a Gaussian-weighted local affine fit of camera position
   against decoded projector position over the camera pixels that decoded near it (the map
   ``camera = a + B (p - X)`` evaluated at ``X``), which averages the phase noise of many camera pixels
   and is exact for locally affine maps. Kept where the samples surround ``X`` (centroid and spread),
   the fit is consistent (residual) and the answer lies in the camera frame; everywhere else invalid.

``opencv-graycode`` (OpenCV's ``GrayCodePattern`` layout, dense, sub-pixel from the stripe edges):
:mod:`projsynth.structured.edges` per camera pixel, then the same step 2. Its photos come either named
as the patterns or, with ``layout="opencv"``, as any folder in name order for a given projector size.

``dots`` (the paper's sparse protocol): :mod:`projsynth.structured.dots`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset.shards import is_dataset_file
from ..errors import ProjsynthError
from ..flow.formats import encode_flow_exr
from ..utils.files import remove_stale_temporaries, write_atomic_all
from ..utils.images import IMAGE_EXTENSIONS, load_gray
from ..utils.outputs import folder_files, refuse_foreign_files, refuse_overwriting_inputs
from .captured import captured_samples, require_captured_out, write_captured_dataset
from .dots import decode_dots
from .edges import decode_edges, window_noise
from .graybits import bits_agree, gray_stripe
from .invert import invert_map
from .patterns import PatternSet, opencv_set, read_patterns

SATURATED = 0.995  # of full scale: a fringe photo at or above this at a pixel rejects the pixel
MIN_CONTRAST = 0.02  # white - black, of full scale
MIN_MODULATION = 0.15  # fringe amplitude / (white - black)
MIN_BIT_CONTRAST = 0.2  # |pattern - inverse| / (white - black) of a clear bit
MAX_BEYOND = 0.05  # share of lit camera pixels decoding beyond the given projector size that refuses it
MIN_DECODED = 0.01  # share of projector pixels (graycode) or dots (dots) below which a decode is refused


@dataclass(frozen=True)
class Correspondence:
    """A decoded forward map: ``flow`` ``(H, W, 2)`` float32 camera px - projector px, ``valid`` ``(H, W)``."""

    flow: np.ndarray
    valid: np.ndarray
    stats: dict


def load_captures(
    patterns: PatternSet, folder: Path, loader: Callable[[Path], np.ndarray] = load_gray
) -> tuple[np.ndarray, list[Path]]:
    """The photos of ``patterns`` in ``folder`` as ``(N, Hc, Wc)`` float32 grey in [0, 1], and their files.

    Photos carry the pattern names with any image extension (8- or 16-bit, colour or grey). ``loader``
    reads one photo (``load_rgb``: ``(N, Hc, Wc, 3)``, the channels apart).

    Raises:
        ProjsynthError: a photo is missing, an extra image is present, a photo is unreadable, or the
            photos differ in size.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ProjsynthError(f"--captures {folder}: not a folder of photos")
    found: dict[str, list[Path]] = {}
    for p in sorted(folder.iterdir()):
        if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS:
            found.setdefault(p.stem, []).append(p)
    names = set(patterns.names)
    extra = sorted(s for s in found if s not in names)
    if extra:
        raise ProjsynthError(
            f"--captures {folder}: {found[extra[0]][0].name} is not a photo of any pattern "
            f"({len(extra)} such); keep only the photos named as the patterns"
        )
    files = []
    for name in patterns.names:
        if name not in found:
            raise ProjsynthError(
                f"--captures {folder}: no photo of pattern {name} (e.g. {name}.png); "
                f"shoot all {len(patterns.names)} patterns in order"
            )
        if len(found[name]) > 1:
            raise ProjsynthError(
                f"--captures {folder}: two photos of pattern {name} "
                f"({', '.join(p.name for p in found[name])}); keep one"
            )
        files.append(found[name][0])
    return _read_photos(files, loader), files


def load_ordered_captures(patterns: PatternSet, folder: Path) -> tuple[np.ndarray, list[Path]]:
    """The photos of an ``opencv-graycode`` set shot with OpenCV's tools: every image directly in ``folder``,
    in name order, as the set's order (OpenCV's files carry no pattern names).

    Name order is natural (``im2`` before ``im10``, as OpenCV's capture sample numbers its files),
    then case-insensitive; hidden files are skipped. Returns ``(N, Hc, Wc)`` float32 grey in [0, 1] and
    the files, as :func:`load_captures`.

    Raises:
        ProjsynthError: the folder is missing, holds another number of images than ``patterns`` has,
            a photo is unreadable, or the photos differ in size.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ProjsynthError(f"--captures {folder}: not a folder of photos")
    files = sorted(
        (
            p
            for p in folder.iterdir()
            if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith(".")
        ),
        key=_natural_key,
    )
    if len(files) != len(patterns.names):
        h, w = patterns.size
        p = patterns.params
        raise ProjsynthError(
            f"--captures {folder}: {len(files)} images, but OpenCV's layout for a {h}x{w} (HxW) projector has "
            f"{len(patterns.names)} ({p['bits_x']} column and {p['bits_y']} row bits, each with its inverse, then "
            "white and black); check --projector (height x width) and keep only those photos in the folder"
        )
    return _read_photos(files), files


def _natural_key(path: Path) -> list:
    return [(0, int(t), "") if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", path.name) if t]


def _read_photos(files: list[Path], loader: Callable[[Path], np.ndarray] = load_gray) -> np.ndarray:
    """``(N, Hc, Wc)`` float32 grey of ``files`` (or what ``loader`` reads); a photo of another size than the
    first is an error."""
    images = [loader(files[0])]
    for f in files[1:]:
        img = loader(f)
        if img.shape[:2] != images[0].shape[:2]:
            raise ProjsynthError(
                f"{f}: {img.shape[1]}x{img.shape[0]} px, but {files[0].name} is "
                f"{images[0].shape[1]}x{images[0].shape[0]}; all photos must come from one camera "
                "setting"
            )
        images.append(img)
    return np.stack(images)


CORRESPONDENCE_FILE, DECODE_FILE = "correspondence.exr", "decode.json"
LAYOUTS = ("projsynth", "opencv")  # how decode finds each pattern's photo: by name, or in name order


def decode_folder(
    patterns_dir: Path | None,
    captures: Path,
    out: Path,
    pairs: list[tuple[Path, Path]] = (),
    layout: str = "projsynth",
    projector: tuple[int, int] | None = None,
) -> str:
    """``projsynth decode``: the photos in ``captures`` of the set in ``patterns_dir`` -> ``out``.

    ``layout`` (``LAYOUTS``): ``projsynth``, photos named as the patterns of ``patterns_dir``; ``opencv``,
    no ``patterns_dir`` but the ``projector``'s ``(H, W)``: a capture in OpenCV's ``GrayCodePattern``
    layout (kind ``opencv-graycode``), its photos taken in name order (:func:`load_ordered_captures`).

    Writes ``out/correspondence.exr`` (channels ``forward.u``, ``forward.v``, ``valid``, as the shards'
    flow) and ``out/decode.json`` (what was decoded, how much is valid); with ``pairs``, ``out`` is
    also a dataset of those pairs with the correspondence as truth (:mod:`projsynth.structured.captured`).

    Returns:
        A one-line summary for the user.
    """
    out = Path(out)
    _check_layout(layout, patterns_dir, projector)
    patterns = read_patterns(patterns_dir) if projector is None else opencv_set(projector)
    inputs = folder_files("--captures", Path(captures))
    inputs += folder_files("--patterns", Path(patterns_dir)) if patterns_dir is not None else []
    inputs += [(option, Path(p)) for pair in pairs for option, p in zip(("--pair", "--pair"), pair, strict=True)]
    refuse_overwriting_inputs([("--out", out)], inputs)
    refuse_foreign_files(out, _decode_owns, "projsynth decode", marks=(CORRESPONDENCE_FILE, DECODE_FILE))
    if projector is None:
        photos, files = load_captures(patterns, captures)
    else:
        photos, files = load_ordered_captures(patterns, captures)
    result = decode(patterns, photos)
    if projector is not None:
        require_in_projector(result, patterns, "--projector")
    require_decoded(result, patterns, photos, f"--captures {captures}")
    camera_size = photos.shape[1:]
    samples = captured_samples(pairs, result.flow, result.valid, camera_size) if pairs else []
    # refused before the earlier decode there is touched
    plan = require_captured_out(out, patterns, patterns_dir, files, samples, camera_size) if samples else None
    record = {
        "patterns": None if patterns_dir is None else str(patterns_dir),
        "layout": layout,
        "kind": patterns.kind,
        "projector_size": list(patterns.size),
        "camera_size": list(camera_size),
        "photos": [f.name for f in files],
        **result.stats,
        "valid_share": float(result.valid.mean()),
    }
    # decode.json is the mark of a finished decode: gone while the others are rewritten, written last
    try:
        (out / DECODE_FILE).unlink(missing_ok=True)
    except OSError as e:
        raise ProjsynthError(f"--out {out / DECODE_FILE}: cannot replace it ({e.strerror or e})") from e
    write_atomic_all(
        [(out / CORRESPONDENCE_FILE, encode_flow_exr(result.flow, result.valid, "correspondence"))], make_parents=True
    )
    if samples:
        write_captured_dataset(out, patterns, patterns_dir, files, samples, camera_size, plan)
        record["dataset_pairs"] = len(samples)
    write_atomic_all([(out / DECODE_FILE, (json.dumps(record, indent=1) + "\n").encode())])
    remove_stale_temporaries(out, [CORRESPONDENCE_FILE, DECODE_FILE])
    what = (
        f"{result.stats['dots_decoded']} of {result.stats['dots']} dots"
        if patterns.kind == "dots"
        else (f"{result.valid.mean():.1%} of projector pixels")
    )
    return f"{what} decoded into {CORRESPONDENCE_FILE}" + (f"; dataset of {len(samples)} pairs" if samples else "")


def _decode_owns(name: str) -> bool:
    """Whether ``name`` is one ``decode`` writes in ``--out``: the correspondence, its record, and the
    dataset of ``--pair``."""
    return name in (CORRESPONDENCE_FILE, DECODE_FILE) or is_dataset_file(name)


def _check_layout(layout: str, patterns_dir: Path | None, projector: tuple[int, int] | None) -> None:
    """Each layout's own options, and only those."""
    if layout not in LAYOUTS:
        raise ProjsynthError(f"--layout: {layout!r} is not one of {', '.join(LAYOUTS)}")
    if layout == "opencv" and patterns_dir is not None:
        raise ProjsynthError("--patterns: OpenCV's layout is given by --projector HxW; drop --patterns")
    if layout == "opencv" and projector is None:
        raise ProjsynthError("--projector: --layout opencv needs the projector's size HxW (e.g. 768x1024)")
    if layout == "projsynth" and projector is not None:
        raise ProjsynthError("--projector: sets OpenCV's layout; add --layout opencv, or drop it")
    if layout == "projsynth" and patterns_dir is None:
        raise ProjsynthError("--patterns: give the folder written by `projsynth patterns` (or --layout opencv)")


def require_in_projector(result: Correspondence, patterns: PatternSet, option: str) -> None:
    """Refuse a projector size the codes contradict (above ``MAX_BEYOND`` of the lit camera pixels decode
    beyond it): most often width and height swapped, which leaves the image count unchanged."""
    beyond = result.stats["camera_pixels_beyond_projector"] / max(result.stats["camera_pixels_lit"], 1)
    if beyond > MAX_BEYOND:
        h, w = patterns.size
        raise ProjsynthError(
            f"{option} {h}x{w}: {beyond:.0%} of the lit camera pixels decode to columns or rows beyond it; "
            f"give the projector's height first (HxW: OpenCV's width=1024, height=768 is 768x1024), or, if the "
            "size is right, check that the photos are of this pattern set and in its order"
        )


def require_decoded(result: Correspondence, patterns: PatternSet, photos: np.ndarray, source: str) -> None:
    """Refuse a decode that found (almost) nothing: below ``MIN_DECODED`` of the projector's pixels
    (``graycode``) or of its dots, naming the likely cause; ``source`` names the photos (an option and
    its folder, or an argument)."""
    if patterns.kind == "dots":
        share = result.stats["dots_decoded"] / max(result.stats["dots"], 1)
    else:
        share = float(result.valid.mean())
    if share >= MIN_DECODED:
        return
    on, off = ("on", "off") if patterns.kind == "dots" else ("white", "black")
    names = [n.split("-", 1)[1] for n in patterns.names]
    contrast = float(np.median(photos[names.index(on)] - photos[names.index(off)]))
    if contrast < MIN_CONTRAST:
        cause = (
            f"the photos of the {on} and {off} patterns barely differ (median {contrast:.1%} of full scale): "
            "the projector was off or hidden, or the exposure far too short or too long"
        )
    else:
        cause = "the photos are lit but do not decode: are they of these patterns, in this order, from one pose?"
    raise ProjsynthError(f"{source}: only {share:.1%} of the projector decoded (need >= {MIN_DECODED:.0%}); {cause}")


def decode(patterns: PatternSet, photos: np.ndarray) -> Correspondence:
    """The correspondence of ``patterns`` from their photos ``(N, Hc, Wc)`` (:func:`load_captures`)."""
    if photos.shape[0] != len(patterns.names):
        raise ProjsynthError(f"{photos.shape[0]} photos for {len(patterns.names)} patterns")
    if patterns.kind == "response":
        raise ProjsynthError("grey levels measure the devices' response, not a correspondence: `projsynth response`")
    stack = {name.split("-", 1)[1]: img for name, img in zip(patterns.names, photos, strict=True)}
    if patterns.kind == "dots":
        flow, valid, stats = decode_dots(patterns, stack)
        return Correspondence(flow, valid, stats)
    if patterns.kind == "opencv-graycode":
        return decode_opencv(patterns, stack)
    return decode_graycode(patterns, stack)


def decode_opencv(patterns: PatternSet, stack: dict[str, np.ndarray]) -> Correspondence:
    """OpenCV's Gray-code layout, sub-pixel from the stripe edges (:mod:`projsynth.structured.edges`),
    inverted to the projector grid as the fringe decode is; ``stack`` as :func:`decode_graycode`'s."""
    p = patterns.params
    xp, yp, ok, noise, counts = decode_edges(stack, p["bits_x"], p["bits_y"], patterns.size)
    stats = {"edge_noise_px": round(noise, 4), **counts}
    # to the frame's edge, as OpenCV's own decoder, whose integer codes reach every pixel the camera sees
    return _on_projector_grid(xp, yp, ok, window_noise(noise), patterns.size, stats, to_frame_edge=True)


# --- graycode ---------------------------------------------------------------------------------------


def decode_graycode(patterns: PatternSet, stack: dict[str, np.ndarray]) -> Correspondence:
    """Dense sub-pixel decode (module docstring); ``stack`` maps pattern names without ``NN-`` to photos."""
    xp, yp, ok, noise = camera_positions(patterns, stack)
    return _on_projector_grid(xp, yp, ok, noise, patterns.size, {"phase_noise_px": round(noise, 4)})


def _on_projector_grid(
    xp: np.ndarray,
    yp: np.ndarray,
    ok: np.ndarray,
    noise: float,
    size: tuple[int, int],
    stats: dict,
    to_frame_edge: bool = False,
) -> Correspondence:
    """Camera -> projector positions (``(Hc, Wc)``, noise in projector px) to the correspondence on the
    projector's ``size`` grid (:func:`~projsynth.structured.invert.invert_map`), with ``stats`` and counts."""
    flow, valid = invert_map(xp, yp, ok, size, noise, to_frame_edge)
    counts = {
        "camera_pixels_decoded": int(ok.sum()),
        "camera_pixels": int(ok.size),
        "projector_pixels_valid": int(valid.sum()),
        "projector_pixels": int(valid.size),
    }
    return Correspondence(flow, valid, {**stats, **counts})


def camera_positions(
    patterns: PatternSet, stack: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Per camera pixel, the projector position it sees: ``(xp, yp, ok)``, ``(Hc, Wc)`` each, and the
    typical noise of one position (projector px, the 75th percentile over decoded pixels)."""
    p = patterns.params
    white, black = stack["white"], stack["black"]
    contrast = white - black
    ok = contrast > MIN_CONTRAST
    coords, noise = [], []
    for axis, size in (("x", patterns.size[1]), ("y", patterns.size[0])):
        bits = [stack[f"gray-{axis}{b}"] - stack[f"gray-{axis}{b}-inv"] for b in range(p[f"bits_{axis}"])]
        coarse = gray_stripe(bits) * p["stripe"] + (p["stripe"] - 1) / 2  # [Hc, Wc] stripe centre, projector px
        fine, modulation, saturated, spread = _phase(stack, axis, p["shifts"], p["period"])
        pos = fine + p["period"] * np.rint((coarse - fine) / p["period"])
        ok &= bits_agree(bits, pos, p["stripe"], MIN_BIT_CONTRAST * contrast)
        ok &= (modulation > MIN_MODULATION * contrast) & ~saturated
        ok &= (pos >= -0.5) & (pos <= size - 0.5)
        coords.append(pos)
        noise.append(spread)
    typical = float(np.percentile(np.maximum(*noise)[ok], 75)) if ok.any() else 0.0
    return coords[0], coords[1], ok, typical


def _phase(stack: dict[str, np.ndarray], axis: str, shifts: int, period: int) -> tuple[np.ndarray, ...]:
    """Per camera pixel along ``axis``: position in ``[0, period)``, fringe amplitude, unusable (fewer
    than 4 unsaturated photos), and the position's noise (projector px, from the residual of the fit).

    The fit is ``I_k = m + a cos(delta_k) + b sin(delta_k)``, phase ``atan2(b, a)``, by least squares over
    the photos that are not saturated (a clipped sample is not a sample of the cosine); with all
    ``shifts`` photos that is the usual closed form.
    """
    deltas = 2 * np.pi * np.arange(shifts) / shifts
    photos = np.stack([stack[f"phase-{axis}{k}"] for k in range(shifts)])  # [N, Hc, Wc]
    basis = np.stack([np.ones(shifts), np.cos(deltas), np.sin(deltas)], 1).astype(np.float32)  # [N, 3]
    coef = np.einsum("kj,khw->jhw", basis, photos) * np.float32(2.0 / shifts)  # [3, Hc, Wc]
    coef[0] *= 0.5
    clipped = photos >= SATURATED
    some = clipped.any(axis=0)
    used = shifts - clipped.sum(axis=0)
    if some.any():  # refit those pixels on their unclipped photos
        keep = (~clipped[:, some].T).astype(np.float64)  # [P, N]
        b64 = basis.astype(np.float64)
        normal = np.einsum("pk,kj,ki->pji", keep, b64, b64) + 1e-6 * np.eye(3)  # (< 3 photos: flagged anyway)
        rhs = np.einsum("pk,kj,kp->pj", keep, b64, photos[:, some])
        coef[:, some] = np.linalg.solve(normal, rhs[..., None])[..., 0].T
    fitted = np.einsum("kj,jhw->khw", basis, coef)
    residual = np.sqrt(np.sum(np.where(clipped, 0, photos - fitted) ** 2, axis=0) / np.maximum(used - 3, 1))
    amplitude = np.hypot(coef[1], coef[2])
    phase = np.arctan2(coef[2], coef[1]).astype(np.float64)  # = 2 pi x / period (mod 2 pi)
    noise = period / (2 * np.pi) * residual / (np.maximum(amplitude, 1e-6) * np.sqrt(np.maximum(used, 1) / 2))
    return np.mod(phase / (2 * np.pi), 1.0) * period, amplitude, used < 4, noise
