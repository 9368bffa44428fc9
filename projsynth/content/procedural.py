"""Built-in procedural sources: deterministic photograph-like and illustration-like images.

Used when no ``--natural``/``--generated`` folder is given. Every image is a pure function of the
passed ``numpy.random.Generator`` state (numpy and OpenCV drawing only, no global state), textured at
several scales so that every small patch carries something to match, and never trivially periodic.

Convention: images are ``H x W x 3`` uint8 RGB, origin top-left, ``x`` right, ``y`` down.
"""

import cv2
import numpy as np

from ..errors import ProjsynthError

KINDS = ("natural", "generated")
THEMES = ("urban", "rural", "prairie", "forest", "ocean")
MIN_SIDE = 32

_F32 = np.float32


def _rgb(*colours: tuple[int, int, int]) -> np.ndarray:
    return np.array(colours, _F32)


# Natural palettes, RGB. Skies are (zenith, horizon).
_SKY = _rgb((95, 140, 205), (185, 205, 228), (120, 130, 150), (175, 180, 190),
            (60, 110, 190), (215, 195, 170))
_CLOUD = _rgb((236, 238, 240))
_FACADE = _rgb((130, 130, 135), (150, 82, 62), (190, 170, 130), (72, 100, 130),
               (208, 203, 192), (105, 95, 90))
_WINDOW = _rgb((38, 48, 60), (232, 210, 150), (120, 150, 182))
_FIELD = _rgb((110, 150, 60), (200, 180, 92), (130, 100, 70), (160, 190, 90), (88, 120, 50), (180, 160, 120))
_GRASS = _rgb((150, 160, 80), (182, 170, 100), (118, 140, 60), (200, 188, 128))
_FOLIAGE = _rgb((40, 90, 40), (70, 120, 50), (100, 140, 60), (50, 80, 35), (122, 152, 70), (30, 62, 34))
_BARK = _rgb((82, 62, 46), (104, 84, 62), (62, 52, 42))
_WATER = _rgb((122, 160, 180), (22, 72, 112), (35, 100, 120))
_FLOWER = _rgb((232, 200, 60), (200, 80, 120), (240, 240, 235), (150, 90, 200))
_DARK = _rgb((58, 78, 56), (70, 64, 60))

# Illustration palettes: saturated flat colours per theme.
_CARTOON = {
    "urban": _rgb((90, 90, 110), (240, 80, 150), (40, 200, 220), (250, 210, 60), (180, 180, 200),
                  (60, 50, 90)),
    "rural": _rgb((110, 190, 80), (200, 50, 40), (250, 220, 90), (120, 180, 240), (150, 100, 60),
                  (240, 240, 220)),
    "prairie": _rgb((235, 190, 70), (240, 130, 50), (110, 170, 230), (130, 180, 70), (250, 240, 200),
                    (170, 90, 50)),
    "forest": _rgb((40, 130, 70), (100, 180, 80), (120, 80, 50), (220, 60, 50), (245, 235, 200),
                   (20, 80, 60)),
    "ocean": _rgb((30, 110, 200), (60, 200, 210), (250, 120, 100), (240, 220, 160), (250, 250, 250),
                  (20, 50, 110)),
}
_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_PLAIN, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_SCRIPT_SIMPLEX, cv2.FONT_HERSHEY_SCRIPT_COMPLEX)
_GLYPHS = np.array(list("ABCDEFGHJKLMNPQRSTUVWXYZabcdefghijkmnopqrstuvwxyz0123456789!?&#@"))


def render_procedural(kind: str, theme: str, size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Render one built-in procedural image.

    Args:
        kind: ``"natural"`` (photograph-like: fractal texture, theme structure, lighting, grain) or
            ``"generated"`` (illustration-like: flat and gradient shapes, thick outlines, glyphs).
        theme: one of ``THEMES``; chooses palette and scene structure.
        size: ``(H, W)``, both at least ``MIN_SIDE``.
        rng: the only source of randomness; the same state gives the same image.

    Returns:
        ``H x W x 3`` uint8 RGB image.

    Convention: origin top-left, ``x`` right, ``y`` down.

    Example:
        >>> img = render_procedural("natural", "forest", (48, 64), np.random.default_rng(0))
        >>> img.shape, img.dtype.name
        ((48, 64, 3), 'uint8')
    """
    if kind not in KINDS:
        raise ProjsynthError(f"procedural kind {kind!r} is unknown; use one of {', '.join(KINDS)}")
    if theme not in THEMES:
        raise ProjsynthError(f"procedural theme {theme!r} is unknown; use one of {', '.join(THEMES)}")
    h, w = (int(v) for v in size)
    if min(h, w) < MIN_SIDE:
        raise ProjsynthError(f"image size {h}x{w} is too small for procedural images; "
                             f"use sides >= {MIN_SIDE}")
    if kind == "natural":
        return _finish(rng, _NATURAL[theme](rng, h, w))
    return _generated(rng, theme, h, w)


# --- shared helpers -----------------------------------------------------------------------------
# Natural images are built channels-first, float32 [3, H, W]: numpy broadcasts a colour (3, 1, 1) or a
# scalar field (H, W) over them with long inner loops, several times faster than over H x W x 3.
# Binary operations put the full-size operand first: numpy then iterates in its memory order (up to
# 20x faster than when a broadcast operand comes first).


def _noise(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Zero-mean unit-variance uniform noise (several times faster than float32 normals)."""
    return (rng.random(shape, dtype=_F32) - 0.5) * np.float32(12**0.5)


def _fbm(rng: np.random.Generator, h: int, w: int, scale: float, gain: float = 0.55) -> np.ndarray:
    """Fractal value noise ``[h, w]`` float32, zero mean, unit std.

    ``scale`` is the coarsest wavelength in pixels; octaves double the grid up to ~2 px detail, each
    octave being the running sum upsampled (cubic) plus new noise, so the cost is ~1.3 full resizes.
    """
    gh, gw = max(2, int(np.ceil(h / scale)) + 1), max(2, int(np.ceil(w / scale)) + 1)
    acc, amp = _noise(rng, (gh, gw)), 1.0
    while 4 * gh <= h + 4 or 4 * gw <= w + 4:
        gh, gw, amp = 2 * gh, 2 * gw, amp * gain
        acc = cv2.resize(acc, (gw, gh), interpolation=cv2.INTER_CUBIC) + amp * _noise(rng, (gh, gw))
    acc = cv2.resize(acc, (w, h), interpolation=cv2.INTER_CUBIC)
    mean, std = cv2.meanStdDev(acc)
    return (acc - np.float32(mean[0, 0])) * np.float32(1 / (std[0, 0] + 1e-6))


def _curve(rng: np.random.Generator, n: int, knots: int) -> np.ndarray:
    """A smooth random 1-D profile of length ``n`` in about [-1, 1]."""
    grid = rng.uniform(-1, 1, (1, knots)).astype(_F32)
    return cv2.resize(grid, (n, 1), interpolation=cv2.INTER_CUBIC)[0]


def _pick(rng: np.random.Generator, palette: np.ndarray, jitter: float = 12.0) -> np.ndarray:
    """A jittered palette colour, shape (3,)."""
    return palette[rng.integers(len(palette))] + rng.uniform(-jitter, jitter, 3).astype(_F32)


def _c(colour: np.ndarray) -> np.ndarray:
    return colour.reshape(3, 1, 1)


def _sky(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    top, bottom = _SKY[2 * rng.integers(3)], _SKY[2 * rng.integers(3) + 1]
    t = np.linspace(0, 1, h, dtype=_F32)[None, :, None]
    grad = _c(top) * (1 - t) + _c(bottom) * t  # [3, h, 1]
    alpha = np.clip((_fbm(rng, h, w, scale=0.6 * max(h, w / 2)) - rng.uniform(-0.4, 1.0)) * 0.7, 0, 1)
    return alpha * (_c(_CLOUD[0]) - grad) + grad


def _finish(rng: np.random.Generator, img: np.ndarray) -> np.ndarray:
    """Lighting, one hard-edged shadow, fine texture and grain; ``[3, H, W]`` float -> ``H x W x 3`` uint8."""
    h, w = img.shape[1:]
    a, k = rng.uniform(0, 2 * np.pi), rng.uniform(0.1, 0.35)
    # Darken-only lighting, in [1 - k, 1], so that bright palettes (clouds, foam) never saturate flat.
    ramp = np.float32(np.cos(a)) * np.linspace(-1, 1, w, dtype=_F32) + np.zeros((h, 1), _F32)
    light = 1 - k * (0.5 + 0.35 * (ramp + np.float32(np.sin(a)) * np.linspace(-1, 1, h, dtype=_F32)[:, None]))
    if rng.random() < 0.6:
        pts = (rng.uniform(-0.3, 1.3, (int(rng.integers(3, 7)), 2)) * (w, h)).astype(np.int32)
        shadow = np.zeros((h, w), np.uint8)
        cv2.fillPoly(shadow, [cv2.convexHull(pts)], 1)
        light *= 1 - np.float32(rng.uniform(0.15, 0.35)) * shadow
    img *= light
    # Every 8 x 8 patch gets texture: fine fractal detail plus per-pixel grain (grey, like luminance noise).
    texture = 9.0 * _fbm(rng, h, w, scale=16.0, gain=0.7)
    texture += 3.0 * _noise(rng, (h, w)) + 0.5
    img += texture
    np.clip(img, 0, 255, out=img)
    return cv2.merge([plane.astype(np.uint8) for plane in img])


# --- natural themes: float32 [3, H, W] before _finish ---------------------------------------------


def _urban(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    img, s = _sky(rng, h, w), min(h, w)
    ground = int(h * rng.uniform(0.78, 0.95))
    texture = 1 + 0.2 * _fbm(rng, h, w, scale=0.2 * s)
    img[:, ground:] = texture[ground:] * _c(_pick(rng, _rgb((72, 72, 78), (96, 92, 88))))
    x = int(rng.integers(-s // 8, 1))
    while x < w:
        x1, top = x + max(3, int(rng.uniform(0.15, 0.6) * s)), int(h * rng.uniform(0.02, 0.5))
        cols = slice(max(x, 0), min(x1, w))
        _facade(rng, img[:, top:ground, cols], texture[top:ground, cols], s)
        x = x1
    return img


def _facade(rng: np.random.Generator, view: np.ndarray, texture: np.ndarray, s: int) -> None:
    """Paint a facade with a jittered window grid into ``view`` ``[3, fh, fw]`` (in place)."""
    fh, fw = view.shape[1:]
    view[:] = texture * _c(_pick(rng, _FACADE, 18))
    view[:, :, : max(1, fw // 12)] *= 0.75  # the shaded side gives the block depth
    px = rng.uniform(0.03, 0.1) * s
    py = px * rng.uniform(0.8, 1.7)
    ys, xs = np.arange(fh) - rng.uniform(0, py), np.arange(fw) - rng.uniform(0, px)
    iy, ix = np.floor(ys / py).astype(np.int64) + 1, np.floor(xs / px).astype(np.int64) + 1
    inside_y = ys - (iy - 1) * py < py * rng.uniform(0.4, 0.75)
    inside_x = xs - (ix - 1) * px < px * rng.uniform(0.35, 0.75)
    inside_x &= np.abs(np.arange(fw) - fw / 2) < 0.4 * fw  # margins at the facade's ends
    mask = inside_y[:, None] & inside_x[None, :]
    # Each window: dark to sky-reflecting glass, or lit (one in five).
    state = rng.random((iy.max() + 1, ix.max() + 1)).astype(_F32)[iy[:, None], ix[None, :]][mask]
    glass = _WINDOW[0][:, None] + (state / 0.8) * (_WINDOW[2] - _WINDOW[0])[:, None]
    view[:, mask] = np.where(state > 0.8, _WINDOW[1][:, None], glass)


def _rural(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    img, s = np.empty((3, h, w), _F32), min(h, w)
    hz = int(h * rng.uniform(0.0, 0.35)) if rng.random() < 0.8 else 0
    if hz > 0:
        img[:, :hz] = _sky(rng, hz, w)
    fh = h - hz
    n = min(255, max(4, int(rng.uniform(8, 22) * h * w / s**2 * (1.3 if hz == 0 else 1.0))))
    # Voronoi fields, more seeds near the horizon: distant fields look smaller.
    sy, sx = (fh * rng.random(n) ** 1.6).astype(np.int64), rng.integers(0, w, n)
    seeds = np.full((fh, w), 255, np.uint8)
    seeds[sy, sx] = 0
    _, lab = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    field = np.zeros(lab.max() + 1, np.uint8)
    field[lab[sy, sx]] = np.arange(n)
    lab = field[lab]

    def per_field(values: np.ndarray) -> np.ndarray:  # cv2.LUT: ~4x faster than numpy fancy indexing
        return cv2.LUT(lab, np.pad(values.astype(_F32), (0, 256 - n)))

    # Furrows: per field a direction and spacing, bent by noise.
    ang, freq = rng.uniform(0, np.pi, n), 2 * np.pi / (rng.uniform(0.008, 0.035, n) * s)
    phase = per_field(np.cos(ang) * freq) * np.arange(w, dtype=_F32)
    phase += per_field(np.sin(ang) * freq) * np.arange(fh, dtype=_F32)[:, None]
    phase += 1.5 * _fbm(rng, fh, w, scale=0.15 * s)
    shade = np.sin(phase) * per_field(rng.uniform(0.08, 0.3, n)) + 1
    colour = np.stack([_pick(rng, _FIELD, 15) for _ in range(n)], 1)  # [3, n]
    for k in range(3):
        np.multiply(shade, per_field(colour[k]), out=img[k, hz:])
    edge = (np.diff(lab, axis=0, prepend=lab[:1]) != 0) | (np.diff(lab, axis=1, prepend=lab[:, :1]) != 0)
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    img[:, hz:][:, edge] = _DARK[0][:, None]  # hedgerows
    return img


def _prairie(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    s = min(h, w)
    hz = int(h * rng.uniform(0.25, 0.55))
    img = np.empty((3, h, w), _F32)
    img[:, :hz] = _sky(rng, hz, w)
    fh = h - hz
    c0, c1 = _c(_pick(rng, _GRASS)), _c(_pick(rng, _GRASS))
    mix = np.clip(0.5 + 0.4 * _fbm(rng, fh, w, scale=0.5 * s), 0, 1)
    # Grass blades: noise stretched vertically, stronger in the foreground.
    blade = _noise(rng, (max(2, fh // max(3, s // 48)), max(2, int(w / 1.5))))
    blade = cv2.resize(blade, (w, fh), interpolation=cv2.INTER_CUBIC)
    depth = np.linspace(0.3, 1.0, fh, dtype=_F32)[:, None]
    img[:, hz:] = (mix * (c1 - c0) + c0) * (1 + 0.18 * blade * depth)
    # A tree line on the horizon: a sharp, non-repeating silhouette.
    tops = hz - (h * rng.uniform(0.0, 0.06) * (1 + _curve(rng, w, int(rng.integers(6, 30))))).astype(np.int64)
    band = slice(max(0, int(tops.min())), hz)
    rows = np.arange(band.start, hz)[:, None]
    trees = rows >= tops[None, :]
    leaves = 1 + 0.3 * _fbm(rng, max(1, hz - band.start), w, scale=0.05 * s)
    img[:, band][:, trees] = _pick(rng, _DARK)[:, None] * leaves[trees]
    n = int(rng.uniform(0, 0.004) * fh * w)
    fy, fx = rng.integers(hz + fh // 3, h, n), rng.integers(0, w, n)
    img[:, fy, fx] = _FLOWER[rng.integers(len(_FLOWER), size=n)].T
    return img


def _forest(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    s, area = min(h, w), h * w / min(h, w) ** 2
    canvas = np.empty((h, w, 3), np.uint8)
    canvas[:] = _pick(rng, _FOLIAGE[[3, 5]]).astype(np.uint8)
    _blobs(rng, canvas, int(60 * area), (0.03, 0.12), s, shade=0.7)
    for _ in range(int(rng.integers(3, 10) * area)):
        x, wd = rng.uniform(0, w), rng.uniform(0.015, 0.09) * s
        lean = rng.uniform(-0.06, 0.06) * h
        pts = np.array([[x - wd, h], [x + wd, h], [x + lean + 0.6 * wd, -1], [x + lean - 0.6 * wd, -1]])
        bark = _pick(rng, _BARK, 10)
        cv2.fillConvexPoly(canvas, pts.astype(np.int32), bark.tolist())
        for _ in range(int(rng.integers(2, 6))):  # bark cracks
            dx, (y0, y1) = rng.uniform(-0.5, 0.5) * wd, sorted(rng.uniform(0, h, 2))
            p0, p1 = (x + dx + lean * (1 - y0 / h), y0), (x + dx + lean * (1 - y1 / h), y1)
            cv2.line(canvas, np.int32(p0).tolist(), np.int32(p1).tolist(), (0.6 * bark).tolist(), 1)
    _blobs(rng, canvas, int(90 * area), (0.01, 0.08), s, shade=1.1)
    img = np.stack(cv2.split(canvas)).astype(_F32)
    img *= 1 + 0.25 * _fbm(rng, h, w, scale=0.3 * s)
    return img


def _blobs(rng: np.random.Generator, canvas: np.ndarray, n: int, radius: tuple[float, float], s: int,
           shade: float) -> None:
    h, w = canvas.shape[:2]
    for _ in range(n):
        r = max(1, int(rng.uniform(*radius) * s))
        c = (int(rng.integers(-r, w + r)), int(rng.integers(-r, h + r)))
        cv2.circle(canvas, c, r, np.clip(shade * _pick(rng, _FOLIAGE, 15), 0, 255).tolist(), -1)


def _ocean(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    s = min(h, w)
    hz = int(h * rng.uniform(0.2, 0.5))
    img = np.empty((3, h, w), _F32)
    img[:, :hz] = _sky(rng, hz, w)
    fh = h - hz
    # Waves on a ground plane seen in perspective, computed at half resolution (they are smooth).
    hh, hw = max(2, fh // 2), max(2, w // 2)
    d = ((np.arange(hh, dtype=_F32) + 0.5) / hh)[:, None]
    z = 1 / (d + 0.03)
    x = (np.arange(hw, dtype=_F32) / hw - 0.5) * z * (w / s)
    waves = 0.4 * _fbm(rng, hh, hw, scale=0.3 * s)
    for _ in range(3):
        kz, kx = rng.uniform(2, 6) * s / 384, rng.uniform(-2, 2) * s / 384
        waves += np.sin(kx * x + kz * z + rng.uniform(0, 2 * np.pi)).astype(_F32)
    waves = cv2.resize(waves * np.sqrt(d), (w, fh), interpolation=cv2.INTER_CUBIC)
    t = np.linspace(0, 1, fh, dtype=_F32)[:, None] ** 0.6
    far, near = _c(_pick(rng, _WATER[:1])), _c(_pick(rng, _WATER[1:]))
    water = (1 + 0.3 * waves) * (t * (near - far) + far)
    foam = (waves > rng.uniform(0.9, 1.4)) & (rng.random((fh, w), dtype=_F32) < 0.35)
    water[:, foam] = _CLOUD[0][:, None]
    img[:, hz:] = water
    if rng.random() < 0.6:  # a distant island on the horizon
        x0, x1 = np.sort(rng.integers(0, w, 2))
        prof = hz - (rng.uniform(0.02, 0.12) * h * np.sin(np.linspace(0, np.pi, x1 - x0)) ** 0.5)
        poly = np.concatenate([np.stack([np.arange(x0, x1), prof], 1), [[x1, hz], [x0, hz]]])
        island = np.zeros((h, w), np.uint8)
        cv2.fillPoly(island, [poly.astype(np.int32)], 1)
        img[:, island > 0] = _pick(rng, _DARK)[:, None]
    return img


_NATURAL = {"urban": _urban, "rural": _rural, "prairie": _prairie, "forest": _forest, "ocean": _ocean}


# --- generated (illustration / animation-frame-like) ----------------------------------------------


def _generated(rng: np.random.Generator, theme: str, h: int, w: int) -> np.ndarray:
    pal, s = _CARTOON[theme], min(h, w)
    area = h * w / s**2
    c0, c1 = _pick(rng, pal, 25), _pick(rng, pal, 25)
    tilt = np.float32(rng.uniform(-0.5, 0.5))
    t = np.linspace(0, 1, w, dtype=_F32) * tilt + np.linspace(0, 1, h, dtype=_F32)[:, None]
    t = (t - t.min()) * (1 / (t.max() - t.min()))
    img = cv2.merge([t * (c1[i] - c0[i]) + c0[i] for i in range(3)]).astype(np.uint8)
    _MOTIFS[theme](rng, img, pal, s)
    # A few large shapes, more medium ones, many small ones.
    for count, size in ((4, (0.15, 0.4)), (18, (0.05, 0.15)), (50, (0.015, 0.05))):
        _shapes(rng, img, pal, int(rng.uniform(0.6, 1.4) * count * area), size, s)
    _glyphs(rng, img, pal, s)
    # Keep clear of 0 and 255 so that the paper / print grain never clips to a flat tile.
    img = cv2.convertScaleAbs(img, alpha=223 / 255, beta=16)
    texture = 8.0 * _fbm(rng, h, w, scale=16.0, gain=0.7) + 2.0 * _noise(rng, (h, w))
    return cv2.add(img, cv2.merge([texture] * 3), dtype=cv2.CV_8U)


def _ink(rng: np.random.Generator) -> list[float]:
    return rng.uniform(10, 60, 3).tolist()


def _thick(rng: np.random.Generator, r: float) -> int:
    return int(np.clip(r * rng.uniform(0.04, 0.12), 1, 8))


def _shapes(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, n: int, size: tuple[float, float],
            s: int) -> None:
    """Draw ``n`` polygons, stars, ellipses or slabs: flat, gradient or stripe filled, most outlined."""
    h, w = img.shape[:2]
    cx, cy, r = rng.uniform(0, w, n), rng.uniform(0, h, n), np.maximum(1.5, rng.uniform(*size, n) * s)
    kind, fill = rng.integers(4, size=n), rng.random(n)
    aspect, turn = rng.uniform(0.1, 1.0, n), rng.uniform(0, 1, n)
    colour = np.clip(pal[rng.integers(len(pal), size=(n, 2))] + rng.uniform(-25, 25, (n, 2, 3)), 0, 255)
    ink = rng.uniform(10, 60, (n, 3))
    thick = np.clip(r * rng.uniform(0.04, 0.12, n), 1, 8).astype(int) * (rng.random(n) < 0.7)
    for i in range(n):
        if kind[i] == 0:
            ang = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 9))))
            rad = r[i] * rng.uniform(0.5, 1.0, len(ang))
        elif kind[i] == 1:
            ang = np.linspace(0, 2 * np.pi, 2 * int(3 + 6 * aspect[i]), endpoint=False) + np.pi * turn[i]
            rad = r[i] * np.where(np.arange(len(ang)) % 2, 0.3 + 0.3 * aspect[i], 1.0)
        if kind[i] < 2:
            pts = np.stack([cx[i] + rad * np.cos(ang), cy[i] + rad * np.sin(ang)], 1).astype(np.int32)
        elif kind[i] == 2:
            axes = (int(r[i]), max(1, int(r[i] * aspect[i])))
            pts = cv2.ellipse2Poly((int(cx[i]), int(cy[i])), axes, int(180 * turn[i]), 0, 360, 10)
        else:
            box = ((cx[i], cy[i]), (2 * r[i], 2 * r[i] * aspect[i]), 180 * turn[i])
            pts = cv2.boxPoints(box).astype(np.int32)
        if fill[i] < 0.5:
            cv2.fillPoly(img, [pts], colour[i, 0].tolist(), cv2.LINE_AA)
        else:
            stripe = 0.0 if fill[i] < 0.75 else rng.uniform(2.0, 0.2 * r[i] + 3.0)
            _pattern_fill(img, pts, colour[i], 2 * np.pi * turn[i], stripe)
        if thick[i]:
            cv2.polylines(img, [pts], True, ink[i].tolist(), int(thick[i]), cv2.LINE_AA)


def _pattern_fill(img: np.ndarray, pts: np.ndarray, colour: np.ndarray, angle: float, stripe: float) -> None:
    """Fill polygon ``pts`` with a linear gradient (``stripe == 0``) or stripes ``stripe`` px wide."""
    h, w = img.shape[:2]
    x0, y0 = np.maximum(pts.min(0), 0)
    x1, y1 = np.minimum(pts.max(0) + 1, (w, h))
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(mask, [pts - (x0, y0)], 255, cv2.LINE_AA)
    u = np.arange(y1 - y0, dtype=_F32)[:, None] * np.float32(np.sin(angle))
    u = u + np.float32(np.cos(angle)) * np.arange(x1 - x0, dtype=_F32)
    t = np.floor(u * (1 / stripe)) % 2 if stripe else (u - u.min()) * (1 / (np.ptp(u) + 1e-6))
    c0, dc = colour[0], colour[1] - colour[0]
    paint = cv2.merge([t * np.float32(dc[k]) + np.float32(c0[k]) for k in range(3)]).astype(np.uint8)
    weight = mask.astype(_F32) * (1 / 255)
    patch = img[y0:y1, x0:x1]
    patch[:] = cv2.blendLinear(paint, patch, weight, 1 - weight)


def _glyphs(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    for _ in range(int(rng.integers(2, 8) * h * w / s**2)):
        text = "".join(rng.choice(_GLYPHS, int(rng.integers(2, 10))))
        font, scale = _FONTS[rng.integers(len(_FONTS))], rng.uniform(0.3, 1.8) * s / 384
        thick = max(1, round(scale * rng.uniform(1, 3)))
        org = (int(rng.uniform(-0.1, 0.9) * w), int(rng.uniform(0.1, 1.0) * h))
        if rng.random() < 0.5:
            cv2.putText(img, text, org, font, scale, _ink(rng), thick + 2 * max(1, thick // 2), cv2.LINE_AA)
        cv2.putText(img, text, org, font, scale, _pick(rng, pal, 25).tolist(), thick, cv2.LINE_AA)


def _skyline(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    ground, x = int(h * rng.uniform(0.75, 0.95)), 0
    while x < w:
        bw, top = int(rng.uniform(0.08, 0.3) * s) + 2, int(h * rng.uniform(0.15, 0.6))
        cv2.rectangle(img, (x, top), (x + bw, ground), _pick(rng, pal, 25).tolist(), -1)
        step, win = int(rng.uniform(0.03, 0.07) * s) + 3, _pick(rng, pal, 25).tolist()
        for yy in range(top + step // 2, ground - step, step):
            for xx, on in zip(range(x + step // 2, x + bw - step, step), rng.random(bw) < 0.6, strict=False):
                if on:
                    cv2.rectangle(img, (xx, yy), (xx + step // 2, yy + step // 2), win, -1)
        cv2.rectangle(img, (x, top), (x + bw, ground), _ink(rng), _thick(rng, 0.5 * bw))
        x += bw


def _hills(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    for base in np.sort(rng.uniform(0.3, 0.85, int(rng.integers(2, 5)))):
        ys = h * (base + 0.12 * _curve(rng, w // 4 + 2, int(rng.integers(3, 8))))
        edge = np.stack([np.linspace(0, w, len(ys)), ys], 1)
        poly = np.concatenate([edge, [[w, h], [0, h]]]).astype(np.int32)
        cv2.fillPoly(img, [poly], _pick(rng, pal, 25).tolist(), cv2.LINE_AA)
        cv2.polylines(img, [edge.astype(np.int32)], False, _ink(rng), _thick(rng, 0.1 * s), cv2.LINE_AA)


def _sunny_plain(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    hz = int(h * rng.uniform(0.4, 0.65))
    img[hz:] = np.clip(_pick(rng, pal, 25), 0, 255).astype(np.uint8)
    sun, r = (int(rng.uniform(0, w)), int(rng.uniform(0, hz))), int(rng.uniform(0.05, 0.15) * s) + 2
    for a in np.linspace(0, 2 * np.pi, int(rng.integers(8, 16)), endpoint=False) + rng.uniform(0, 1):
        tip = (int(sun[0] + 2 * r * np.cos(a)), int(sun[1] + 2 * r * np.sin(a)))
        cv2.line(img, sun, tip, _pick(rng, pal, 20).tolist(), _thick(rng, r), cv2.LINE_AA)
    cv2.circle(img, sun, r, _pick(rng, pal, 20).tolist(), -1, cv2.LINE_AA)
    n = int(120 * h * w / s**2)
    x, y = rng.uniform(0, w, n), rng.uniform(hz, h, n)
    ln = (y - hz + 4) * rng.uniform(0.03, 0.12, n)
    tips = np.stack([x + rng.uniform(-0.4, 0.4, n) * ln, y - ln], 1).astype(int).tolist()
    colours = np.clip(pal[rng.integers(len(pal), size=n)] + rng.uniform(-30, 30, (n, 3)), 0, 255).tolist()
    for base, tip, colour in zip(np.stack([x, y], 1).astype(int).tolist(), tips, colours, strict=True):
        cv2.line(img, base, tip, colour, 1, cv2.LINE_AA)


def _firs(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    for _ in range(int(rng.integers(8, 20) * h * w / s**2)):
        x, base, size = rng.uniform(0, w), rng.uniform(0.4, 1.1) * h, rng.uniform(0.08, 0.3) * s
        cv2.rectangle(img, (int(x - size / 8), int(base - size)), (int(x + size / 8), int(base)),
                      _pick(rng, pal, 20).tolist(), -1)
        green = _pick(rng, pal[:2], 25).tolist()
        for k in range(int(rng.integers(2, 4))):
            y = base - size * (0.5 + 0.6 * k)
            half = size * (0.6 - 0.12 * k)
            tri = np.array([[x - half, y], [x + half, y], [x, y - size]])
            cv2.fillPoly(img, [tri.astype(np.int32)], green, cv2.LINE_AA)
            cv2.polylines(img, [tri.astype(np.int32)], True, _ink(rng), _thick(rng, size), cv2.LINE_AA)


def _wave_bands(rng: np.random.Generator, img: np.ndarray, pal: np.ndarray, s: int) -> None:
    h, w = img.shape[:2]
    xs = np.linspace(0, w, max(8, w // 4))
    for top in np.sort(rng.uniform(0.3, 0.9, int(rng.integers(3, 7)))) * h:
        amp, k = rng.uniform(0.01, 0.05) * s, rng.uniform(4, 20) * 2 * np.pi / w
        edge = np.stack([xs, top + amp * np.sin(k * xs + rng.uniform(0, 2 * np.pi))], 1)
        poly = np.concatenate([edge, [[w, h], [0, h]]]).astype(np.int32)
        cv2.fillPoly(img, [poly], _pick(rng, pal[:2], 30).tolist(), cv2.LINE_AA)
        cv2.polylines(img, [edge.astype(np.int32)], False, _pick(rng, pal[3:5], 10).tolist(),
                      _thick(rng, 0.1 * s), cv2.LINE_AA)


_MOTIFS = {"urban": _skyline, "rural": _hills, "prairie": _sunny_plain, "forest": _firs, "ocean": _wave_bands}
