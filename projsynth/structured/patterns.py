"""Structured-light pattern sets for real rigs: what the projector shows to measure its own flow.

Two kinds (docs/real-rig.md):

* ``graycode``: dense and sub-pixel. A white and a black reference, Gray-code stripes for columns
  and for rows (each bit with its inverse), then ``shifts`` phase-shifted cosine fringes of period
  ``period`` px along x and along y. The Gray code names the fringe period a camera pixel sees, the
  fringes its position inside it: ``x = phase / 2 pi * period + period * k``. The Gray code goes
  down to stripes ``period / 4`` wide, so the decoder unwraps correctly while its stripe is off by
  up to one; finer bits would only add photos that defocus blurs away.
* ``dots``: the paper's protocol (its section 5.3): a ``gy x gx`` grid of dots, one all-dots-on and one
  all-off image, then one image per bit of the dot's index (binary code, 9 bits for 400 dots): dot ``i``
  is lit in bit image ``b`` when bit ``b`` of ``i`` is 1. 20 x 20 dots: 11 images. Dot centres sit at
  integer projector pixels; a dot is the disc of pixels within ``radius`` of its centre (symmetric,
  so its centroid is its centre).
* ``opencv-graycode``: the layout of OpenCV's ``cv::structured_light::GrayCodePattern``, so that
  captures shot with OpenCV's tools decode here. For a ``W x H`` projector, ``ceil(log2 W)`` column bits
  and ``ceil(log2 H)`` row bits of the reflected Gray code ``g = n ^ (n >> 1)`` of the column (row)
  index ``n``; bit ``b`` is white where bit ``b`` of ``g`` is 1. Order: for each column bit from the
  most significant down, the pattern then its inverse; the same for the rows; then a white and a black
  image (OpenCV's ``getImagesForShadowMasks``, appended in that order by its capture sample). No
  fringes: the decoder finds sub-pixel positions from where each pattern and its inverse cross.
* ``response``: ``levels`` uniform grey frames, the same value on every pixel and channel, at code values
  ``round(255 k / (levels - 1))`` from black to white (17 by default: 0, 16, 32, ..., 239, 255). Their photos
  measure the camera's and the projector's response curves (:mod:`projsynth.structured.response`), not a
  correspondence.

Convention: images ``(H, W)`` uint8 grey; x right, y down, pixel centres at integers. Pattern names
are ``NN-<name>`` with ``NN`` the position in the projection order; files are ``NN-<name>.png``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataset.plan import MAX_SIZE, MIN_SIZE
from ..errors import ProjsynthError
from ..utils.files import remove_stale_temporaries, write_atomic_all
from ..utils.images import png_bytes

PATTERN_FORMAT = 1
PATTERNS_FILE = "patterns.json"
KINDS = ("graycode", "dots", "opencv-graycode", "response")
DEFAULT_PERIOD, DEFAULT_SHIFTS, DEFAULT_GRID = 16, 8, (20, 20)
MIN_PERIOD, MAX_PERIOD = 8, 1024  # fringe period, projector px
MIN_SHIFTS, MAX_SHIFTS = 3, 64  # phase shifts per axis (each one photo)
MIN_GRID, MAX_GRID = 2, 256  # dots per side
# grey levels of the response set: 17 steps 16 code values apart sample a display's curve finely enough for
# the fit's interpolation (docs/design.md, "The devices' response, measured"); every code value at most
DEFAULT_LEVELS, MIN_LEVELS, MAX_LEVELS = 17, 5, 256


@dataclass(frozen=True)
class PatternSet:
    """A sequence of patterns to project, in order, and what the decoder needs to know about it."""

    kind: str
    size: tuple[int, int]  # projector (H, W)
    names: tuple[str, ...]  # "NN-<name>", projection order
    params: dict = field(default_factory=dict)

    def describe(self) -> dict:
        """The JSON written as ``patterns.json``."""
        return {
            "format_version": PATTERN_FORMAT,
            "kind": self.kind,
            "size": list(self.size),
            "order": [f"{n}.png" for n in self.names],
            "parameters": self.params,
        }

    def images(self) -> list[np.ndarray]:
        """The patterns as ``(H, W)`` uint8 images, in ``names`` order."""
        if self.kind == "opencv-graycode":
            return opencv_images(self)
        if self.kind == "response":
            return [np.full(self.size, v, np.uint8) for v in self.params["levels"]]
        return graycode_images(self) if self.kind == "graycode" else dot_images(self)


def graycode_set(
    size: tuple[int, int], period: int = DEFAULT_PERIOD, shifts: int = DEFAULT_SHIFTS, source: str | None = None
) -> PatternSet:
    """The dense sub-pixel set for an ``H x W`` projector (see the module docstring).

    ``source``: where the values come from, for error messages (None: the command line's options).
    """
    if period < MIN_PERIOD or period > MAX_PERIOD or period % 4:
        raise ProjsynthError(
            f"{_name('period', source)}: must be a multiple of 4 in {MIN_PERIOD}..{MAX_PERIOD}, got {period}"
        )
    if not MIN_SHIFTS <= shifts <= MAX_SHIFTS:
        raise ProjsynthError(f"{_name('shifts', source)}: must be in {MIN_SHIFTS}..{MAX_SHIFTS}, got {shifts}")
    h, w = size
    stripe = period // 4
    bits = {"x": _bits(math.ceil(w / stripe)), "y": _bits(math.ceil(h / stripe))}
    names = ["white", "black"]
    for axis in "xy":
        for b in reversed(range(bits[axis])):  # coarse to fine
            names += [f"gray-{axis}{b}", f"gray-{axis}{b}-inv"]
    for axis in "xy":
        names += [f"phase-{axis}{k}" for k in range(shifts)]
    params = {"period": period, "shifts": shifts, "stripe": stripe, "bits_x": bits["x"], "bits_y": bits["y"]}
    return PatternSet("graycode", (h, w), _numbered(names), params)


def dot_set(size: tuple[int, int], grid: tuple[int, int] = DEFAULT_GRID, source: str | None = None) -> PatternSet:
    """The paper's dot protocol: ``grid`` ``(gy, gx)`` dots, all-on, all-off and one image per index bit."""
    h, w = size
    gy, gx = grid
    if not (MIN_GRID <= gy <= MAX_GRID and MIN_GRID <= gx <= MAX_GRID):
        raise ProjsynthError(f"{_name('grid', source)}: {gy}x{gx} is outside {MIN_GRID}..{MAX_GRID} per side")
    spacing = min((w - 1) / gx, (h - 1) / gy)
    radius = float(math.floor(0.18 * spacing * 2) / 2)
    if radius < 1.5:
        raise ProjsynthError(
            f"{_name('grid', source)} {gy}x{gx}: dots {spacing:.1f} px apart are too close for {h}x{w}; "
            "use fewer dots or a larger size"
        )
    margin_x, margin_y = (w - 1) / gx / 2 + radius, (h - 1) / gy / 2 + radius
    xs = np.rint(np.linspace(margin_x, w - 1 - margin_x, gx)).astype(int)
    ys = np.rint(np.linspace(margin_y, h - 1 - margin_y, gy)).astype(int)
    bits = _bits(gx * gy)
    names = ["on", "off", *(f"bit{b}" for b in range(bits))]
    params = {
        "grid": [gy, gx],
        "radius": radius,
        "bits": bits,
        "code": "binary",
        "centres_x": xs.tolist(),
        "centres_y": ys.tolist(),
    }
    return PatternSet("dots", (h, w), _numbered(names), params)


def opencv_set(size: tuple[int, int]) -> PatternSet:
    """OpenCV's ``GrayCodePattern`` layout for an ``H x W`` projector (module docstring).

    Names: ``col{b}``/``col{b}-inv`` and ``row{b}``/``row{b}-inv`` (``b`` the Gray-code bit, 0 the least
    significant), most significant bit first, then ``white`` and ``black``; ``2 * (bits_x + bits_y) + 2``
    images in all, e.g. 42 for OpenCV's default 1024 x 768.
    """
    h, w = size
    bits = {"col": (w - 1).bit_length(), "row": (h - 1).bit_length()}  # = ceil(log2 n), exactly
    names = []
    for axis in ("col", "row"):
        for b in reversed(range(bits[axis])):
            names += [f"{axis}{b}", f"{axis}{b}-inv"]
    names += ["white", "black"]
    return PatternSet("opencv-graycode", (h, w), _numbered(names), {"bits_x": bits["col"], "bits_y": bits["row"]})


def response_set(size: tuple[int, int], levels: int = DEFAULT_LEVELS, source: str | None = None) -> PatternSet:
    """``levels`` uniform grey frames from black to white for an ``H x W`` projector (module docstring);
    names ``NN-levelVVV`` with ``VVV`` the code value."""
    if not MIN_LEVELS <= levels <= MAX_LEVELS:
        raise ProjsynthError(f"{_name('levels', source)}: must be in {MIN_LEVELS}..{MAX_LEVELS}, got {levels}")
    values = [int(v) for v in np.rint(np.linspace(0, 255, levels))]
    return PatternSet("response", tuple(size), _numbered([f"level{v:03d}" for v in values]), {"levels": values})


def _name(key: str, source: str | None) -> str:
    """How an error names a setting: the option (``--period``) or the file's key (``F: "period"``)."""
    return f"--{key}" if source is None else f'{source}: "{key}"'


def dot_centres(patterns: PatternSet) -> np.ndarray:
    """``(N, 2)`` integer ``(x, y)`` projector centres of the dots, row-major: dot ``i`` is row ``i // gx``."""
    xs, ys = patterns.params["centres_x"], patterns.params["centres_y"]
    gy, gx = patterns.params["grid"]
    return np.array([(xs[i % gx], ys[i // gx]) for i in range(gy * gx)], np.int64)


def graycode_images(patterns: PatternSet) -> list[np.ndarray]:
    h, w = patterns.size
    p = patterns.params
    coords = {"x": np.arange(w)[None, :].repeat(h, 0), "y": np.arange(h)[:, None].repeat(w, 1)}
    images = []
    for name in patterns.names:
        kind = name.split("-", 1)[1]
        if kind in ("white", "black"):
            images.append(np.full((h, w), 255 if kind == "white" else 0, np.uint8))
        elif kind.startswith("gray-"):
            axis, b = kind[5], int(kind[6:].removesuffix("-inv"))
            images.append(_gray_bit(coords[axis] // p["stripe"], b, kind.endswith("-inv")))
        else:
            axis, k = kind[6], int(kind[7:])
            phase = 2 * np.pi * (coords[axis] / p["period"] - k / p["shifts"])
            images.append(np.rint(127.5 + 127.5 * np.cos(phase)).astype(np.uint8))
    return images


def opencv_images(patterns: PatternSet) -> list[np.ndarray]:
    h, w = patterns.size
    index = {"col": np.arange(w)[None, :].repeat(h, 0), "row": np.arange(h)[:, None].repeat(w, 1)}
    flat = {"white": np.full((h, w), 255, np.uint8), "black": np.zeros((h, w), np.uint8)}
    kinds = [name.split("-", 1)[1] for name in patterns.names]
    return [
        flat[k] if k in flat else _gray_bit(index[k[:3]], int(k[3:].removesuffix("-inv")), k.endswith("-inv"))
        for k in kinds
    ]


def _gray_bit(stripe: np.ndarray, b: int, inverse: bool) -> np.ndarray:
    """``(H, W)`` uint8: 255 where bit ``b`` of the Gray code of ``stripe`` is 1 (0 with ``inverse``), else 0."""
    on = ((stripe ^ (stripe >> 1)) >> b) & 1 == 1
    return np.where(on != inverse, 255, 0).astype(np.uint8)


def dot_images(patterns: PatternSet) -> list[np.ndarray]:
    h, w = patterns.size
    r = patterns.params["radius"]
    ri = int(math.ceil(r))
    dy, dx = np.mgrid[-ri : ri + 1, -ri : ri + 1]
    disc = dx * dx + dy * dy <= r * r
    centres = dot_centres(patterns)
    images = []
    for name in patterns.names:
        kind = name.split("-", 1)[1]
        img = np.zeros((h, w), np.uint8)
        for i, (x, y) in enumerate(centres):
            if kind == "on" or (kind.startswith("bit") and (i >> int(kind[3:])) & 1):
                img[y - ri : y + ri + 1, x - ri : x + ri + 1][disc] = 255
        images.append(img)
    return images


def make_set(
    kind: str,
    size: tuple[int, int],
    grid: tuple[int, int] | None = None,
    period: int | None = None,
    shifts: int | None = None,
    levels: int | None = None,
) -> PatternSet:
    """A pattern set by kind name (``KINDS``); a setting of another kind is refused, not ignored."""
    given = {"--grid": grid, "--period": period, "--shifts": shifts, "--levels": levels}
    own = {"graycode": ("--period", "--shifts"), "dots": ("--grid",), "opencv-graycode": (), "response": ("--levels",)}
    if kind not in own:
        raise ProjsynthError(f"--kind: {kind!r} is not one of {', '.join(KINDS)}")
    for option, value in given.items():
        if value is not None and option not in own[kind]:
            owner = next(k for k, options in own.items() if option in options)
            raise ProjsynthError(f"{option}: sets --kind {owner}, not {kind}; drop it")
    check_size(size, "--size")
    if kind == "graycode":
        period = DEFAULT_PERIOD if period is None else period
        return graycode_set(size, period, DEFAULT_SHIFTS if shifts is None else shifts)
    if kind == "dots":
        return dot_set(size, grid or DEFAULT_GRID)
    if kind == "response":
        return response_set(size, DEFAULT_LEVELS if levels is None else levels)
    return opencv_set(size)


def check_size(size: object, option: str) -> None:
    """Refuse a projector size that is not two integers in ``MIN_SIZE..MAX_SIZE`` (as ``--size`` parses)."""
    ok = isinstance(size, tuple | list) and len(size) == 2
    ok = ok and all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in size)
    if not ok or not all(MIN_SIZE <= v <= MAX_SIZE for v in size):
        raise ProjsynthError(f"{option}: expected (height, width) in {MIN_SIZE}..{MAX_SIZE} per side, got {size!r}")


def write_patterns(patterns: PatternSet, out: Path) -> list[Path]:
    """Write the PNGs and ``patterns.json`` into ``out`` (created), all or nothing; the files written.

    A folder that already holds other files is refused unless it holds this very set (its
    ``patterns.json`` the same): photos named after the patterns, the documented way to name them,
    would otherwise be overwritten."""
    out = Path(out)
    _require_free(out, patterns)
    images = zip(patterns.names, patterns.images(), strict=True)
    files = [(out / f"{name}.png", png_bytes(out / name, img)) for name, img in images]
    files.append((out / PATTERNS_FILE, (json.dumps(patterns.describe(), indent=1) + "\n").encode()))
    write_atomic_all(files, make_parents=True)
    remove_stale_temporaries(out, [f.name for f, _ in files])
    return [f for f, _ in files]


def _require_free(out: Path, patterns: PatternSet) -> None:
    """Refuse to write ``patterns`` into a folder that holds files of anything else (:func:`write_patterns`)."""
    if not out.is_dir():
        return
    present = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    if not present:
        return
    try:
        same = json.loads((out / PATTERNS_FILE).read_text()) == json.loads(json.dumps(patterns.describe()))
    except (OSError, ValueError):
        same = False
    if not same:
        raise ProjsynthError(
            f"--out {out}: holds {len(present)} file(s) of something else (e.g. {present[0]}), which the patterns "
            "would overwrite; give a new or empty folder (nothing was written)"
        )


def read_patterns(folder: Path) -> PatternSet:
    """The set described by ``folder/patterns.json`` (the PNGs are not needed to decode).

    Raises:
        ProjsynthError: naming ``patterns.json``: missing, unreadable, of another kind or version, a
            value of the wrong type or outside the bounds ``projsynth patterns`` accepts, or edited.
    """
    path = Path(folder) / PATTERNS_FILE
    again = "write it again with `projsynth patterns`"
    try:
        d = json.loads(path.read_text())
        if d["format_version"] != PATTERN_FORMAT or d["kind"] not in KINDS:
            raise ValueError(f"format {d['format_version']}, kind {d['kind']!r}")
        size = _ints(d["size"], "size")
        names = tuple(str(n).removesuffix(".png") for n in d["order"])
        params = dict(d["parameters"])
    except FileNotFoundError:
        raise ProjsynthError(f"{path}: missing; --patterns must be a folder written by `projsynth patterns`") from None
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise ProjsynthError(f"{path}: not a pattern description ({e}); {again}") from None
    if not all(MIN_SIZE <= v <= MAX_SIZE for v in size):
        raise ProjsynthError(f'{path}: "size" {size[0]}x{size[1]} is outside {MIN_SIZE}..{MAX_SIZE} per side; {again}')
    try:
        if d["kind"] == "graycode":
            expected = graycode_set(
                size, _int(params.get("period"), "period"), _int(params.get("shifts"), "shifts"), source=str(path)
            )
        elif d["kind"] == "opencv-graycode":
            expected = opencv_set(size)
        elif d["kind"] == "response":
            values = params.get("levels")
            count = len(values) if isinstance(values, list) else _int(values, "levels")
            expected = response_set(size, count, source=str(path))
        else:
            expected = dot_set(size, _ints(params.get("grid"), "grid"), source=str(path))
    except ValueError as e:
        raise ProjsynthError(f"{path}: {e}; {again}") from None
    patterns = PatternSet(d["kind"], size, names, params)
    if expected.describe() != patterns.describe():
        raise ProjsynthError(f"{path}: edited or from another version of projsynth; {again}")
    return patterns


def _int(value: object, key: str) -> int:
    if type(value) is not int:  # not a bool, a float or a string
        raise ValueError(f'"{key}" must be an integer, got {json.dumps(value)}')
    return value


def _ints(value: object, key: str) -> tuple[int, int]:
    if not isinstance(value, list) or len(value) != 2:
        raise ValueError(f'"{key}" must be a list of two integers, got {json.dumps(value)}')
    return _int(value[0], key), _int(value[1], key)


def parse_grid(text: str) -> tuple[int, int]:
    """``"20x20"`` -> ``(20, 20)`` (rows x columns of dots)."""
    try:
        gy, gx = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ProjsynthError(f"--grid: expected ROWSxCOLS such as 20x20, got {text!r}") from None
    if not (MIN_GRID <= gy <= MAX_GRID and MIN_GRID <= gx <= MAX_GRID):
        raise ProjsynthError(f"--grid: {gy}x{gx} is outside {MIN_GRID}..{MAX_GRID} per side")
    return gy, gx


def _bits(n: int) -> int:
    """Bits to number ``n`` things (at least 1)."""
    return max(1, math.ceil(math.log2(n)))


def _numbered(names: list[str]) -> tuple[str, ...]:
    return tuple(f"{i:02d}-{n}" for i, n in enumerate(names))
