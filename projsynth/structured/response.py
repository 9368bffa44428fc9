"""The camera's and the projector's response curves, measured from photos of grey levels (``projsynth response``).

Model, per camera pixel ``p`` and colour channel, for a uniform projector code value ``l`` (0..255):

    C = F(o_p + a_p * g(l))

``C`` the camera value (full scale 1), ``F`` the camera's response (linear light -> value), ``g`` the
projector's (code value -> light; ``g(0) = 0``, ``g(255) = 1``, one curve per channel), ``o_p`` the light
on the pixel under a black projection (room light, the projector's black level), ``a_p`` the projector's
gain there (its light, the surface's albedo, vignetting, transparency). ``F^-1(c) = c^exponent`` is a
power law with one exponent for the three channels (a camera applies one tone curve after its colour
matrix); ``g`` is free, sampled at the levels shown and interpolated linearly in ``g^(1/2.2)`` (where a
display's curve is close to a straight line) into a 256-entry table.

**Identifiability.** A power law is scale-free, ``F(t x) = t^(1/exponent) F(x)``: where the room's light is
in the same proportion to the projector's on every pixel (``o_p / a_p`` constant: a dark room, where ``o_p``
is the projector's own black level), every exponent reproduces the photos equally well, with ``g``
bent to match; only the composite ``l -> F(o_p + a_p g(l))`` is measured. Where that proportion varies
over the surface (room light falling differently from the projector's), the photos tell the two
curves apart. The fit scores exponents by the photos' residual (the profile, ``EXPONENTS``); an exponent
fits as well as the best one unless its mean squared residual is higher by ``PROFILE_MARGIN`` per pixel
used (a likelihood-ratio bound counted per pixel, not per sample: a pixel's samples share its errors),
and the exponent counts as **identified** when those span at most ``MAX_INTERVAL`` and stop short of the
grid's ends. Otherwise the fallback (``FALLBACK_EXPONENT``, 2.2, the sRGB-like camera the model assumed
before) is kept and ``g`` fitted under it: the composite still reproduces the photos, which is what
compensation needs on surfaces like the one photographed.

**Fit.** Pixels that the projector lights (every channel's white - black at least ``LIT_CONTRAST``), up to
``MAX_PIXELS`` of them spread over the frame; clipped samples (0, or ``SATURATED`` and above) say only "at
most" or "at least" and are left out. For one exponent, least squares in the camera's values (Gauss-Newton
weights, so the residual is in camera values, not in linear light): each step solves every pixel's
``(o_p, a_p)`` given ``g``, then the levels' ``g`` with those eliminated (variable projection,
Levenberg-Marquardt-damped, halved until the residual falls), ``g`` held at 0 and 1 at the first and last
level. Within three noise sigmas (the residual) of black or white, clipping has removed the samples that
noise pushed past the end and what is left is biased; near black that bias is an offset the model lacks,
which varies against ``a_p`` and would "identify" an exponent on its own, so the profile leaves both ends
out; the curve is then fitted at the chosen exponent with the samples near black back in, which pin
``g(0) = 0`` to the pixels' offsets.

Convention: photos ``(K, Hc, Wc, 3)`` float32 in [0, 1] (full scale), in the order of the levels.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ..errors import ProjsynthError
from ..utils.files import remove_stale_temporaries, write_atomic_all
from ..utils.images import load_rgb
from ..utils.outputs import folder_files, refuse_overwriting_inputs
from ..versions import __version__
from .decode import SATURATED, load_captures
from .patterns import read_patterns

RESPONSE_FORMAT = 1
FALLBACK_EXPONENT = 2.2  # the camera's exponent when the photos cannot tell it (module docstring)
INTERPOLATION = 2.2  # g is interpolated linearly in g^(1/INTERPOLATION) between the levels
EXPONENTS = tuple(np.round(np.arange(0.6, 3.41, 0.2), 2))  # the profile's grid, a linear camera (1) well inside
PROFILE_MARGIN = 4.0  # an exponent fits as well as the best unless it raises the residual by this, per pixel
MAX_INTERVAL = 0.5  # the exponents that fit as well may span this much for the exponent to count as identified
MIN_CONTRAST = 0.02  # median white - black of full scale below which the photos "do not differ"
LIT_CONTRAST = 0.05  # white - black of full scale, every channel, for a pixel to enter the fit
SLOPE_FLOOR = 0.01  # camera value below which the fit's weights stop growing (the response's slope at 0 is infinite)
NEAR_END, NOISE_SIGMAS = 0.02, 3.0  # samples within max(5 DN, 3 x the fit's residual) of black or white: biased
MAX_CLIPPED = 0.5  # share of lit pixels clipped in the white step above which the photos are refused
MAX_PIXELS = 8000  # pixels the fit uses, spread over the lit ones
MIN_PIXELS = 200  # lit pixels below which there is nothing to fit
MIN_SAMPLES = 50  # unclipped samples every level needs
FALL_TOLERANCE = 0.01  # a fitted level darker than the one below it by more than this: refused
MAX_STEPS, CONVERGED = 40, 1e-6  # Gauss-Newton steps per exponent at most; a smaller relative gain ends them
STEP_HALVINGS = 6  # a step that raises the residual is halved this often before the search stops
DAMPING = 1e-3  # Levenberg-Marquardt's, relative to the normal matrix's diagonal


@dataclass(frozen=True, eq=False)
class Response:
    """The devices' curves: ``camera_exponent`` (``F^-1(c) = c^exponent``, ``c`` in [0, 1]) and ``projector``
    ``(3, 256)`` float32, the light of each code value per channel (0 at 0, 1 at 255, increasing).

    ``identified``: whether photos told the camera's exponent apart (False: the fallback, or assumed);
    ``interval``: the exponents that fit the photos as well (None: not measured, e.g. :meth:`from_gamma`);
    ``levels`` and ``points`` ``(3, K)``: the measured ``g``; ``rms_dn``: the fit's residual (8-bit DN).
    """

    camera_exponent: float
    projector: np.ndarray
    identified: bool = True
    interval: tuple[float, float] | None = None
    levels: tuple[int, ...] = ()
    points: np.ndarray | None = None
    rms_dn: float | None = None
    pixels: int = 0

    @classmethod
    def from_gamma(cls, gamma: float) -> Response:
        """One gamma for both devices, assumed (not measured): the model before the response was measured."""
        curve = (np.arange(256, dtype=np.float64) / 255) ** gamma
        return cls(float(gamma), np.tile(curve, (3, 1)).astype(np.float32), identified=False)

    def camera_linear(self, image: np.ndarray) -> np.ndarray:
        """Camera values (uint8 ``(..., 3)``) to linear light, float32."""
        return (image.astype(np.float32) / np.float32(255)) ** np.float32(self.camera_exponent)

    def projector_linear(self, image: np.ndarray) -> np.ndarray:
        """Projector code values (uint8 ``(..., 3)``) to the light they emit, float32 in [0, 1]."""
        return np.stack([self.projector[c][image[..., c]] for c in range(3)], axis=-1)

    def predict(self, black: np.ndarray, white: np.ndarray, level: int) -> np.ndarray:
        """The camera's photo (float, 0-255) of uniform code value ``level`` predicted from its photos of
        black and white (uint8 ``(..., 3)``): the per-pixel model that compensation inverts."""
        offset = self.camera_linear(black)
        light = offset + (self.camera_linear(white) - offset) * self.projector[:, level]
        return 255 * np.clip(light, 0, 1) ** (1 / self.camera_exponent)

    def projector_codes(self, light: np.ndarray) -> np.ndarray:
        """The code values (uint8 ``(..., 3)``) that emit ``light`` (``(..., 3)`` in [0, 1]): the inverse curve."""
        codes = np.arange(256, dtype=np.float32)
        out = [np.interp(light[..., c], self.projector[c], codes) for c in range(3)]
        return np.clip(np.rint(np.stack(out, axis=-1)), 0, 255).astype(np.uint8)


def projector_curve(levels: tuple[int, ...], points: np.ndarray) -> np.ndarray:
    """The 256-entry curves ``(3, 256)`` through ``points`` ``(3, K)`` at code values ``levels``: linear in
    ``g^(1/INTERPOLATION)``, strictly increasing (a flat step is lifted by 1e-6 per code value, so the
    curve can be inverted)."""
    u = np.clip(np.asarray(points, np.float64), 0, 1) ** (1 / INTERPOLATION)
    curve = np.stack([np.interp(np.arange(256), levels, uc) for uc in u]) ** INTERPOLATION
    curve = np.maximum.accumulate(curve + 1e-6 * np.arange(256), axis=1)
    return ((curve - curve[:, :1]) / (curve[:, -1:] - curve[:, :1])).astype(np.float32)


def fit_response(levels: tuple[int, ...], photos: np.ndarray, fallback: float = FALLBACK_EXPONENT) -> Response:
    """The devices' curves from photos of uniform grey ``levels`` (module docstring).

    Args:
        levels: the ``K`` code values shown, increasing, from 0 to 255.
        photos: ``(K, Hc, Wc, 3)`` float32 in [0, 1], in the order of ``levels``.
        fallback: the camera's exponent where the photos do not identify it.

    Raises:
        ProjsynthError: the photos do not differ, light too few pixels, are clipped on most of them, or
            the response they show falls somewhere (photos out of order, the exposure changed).
    """
    levels = tuple(int(v) for v in levels)
    if photos.ndim != 4 or photos.shape[0] != len(levels) or photos.shape[3] != 3:
        raise ProjsynthError(f"{len(levels)} levels need photos (K, H, W, 3), got {photos.shape}")
    if levels[0] != 0 or levels[-1] != 255 or any(b <= a for a, b in zip(levels, levels[1:], strict=False)):
        raise ProjsynthError(f"levels must rise from 0 to 255, got {list(levels)}")
    with threadpool_limits(1, user_api="blas"):  # its matrix products are small: threads would only wait
        return _fit(levels, _samples(levels, photos), fallback)


def _fit(levels: tuple[int, ...], samples: np.ndarray, fallback: float) -> Response:
    """:func:`fit_response` on the samples ``(P, K, 3)`` of the lit pixels."""
    unclipped = (samples > 0) & (samples < SATURATED)  # a clipped sample says only "at least", or "at most"
    counts = unclipped.sum(axis=0).min(axis=1)  # per level, the channel with the fewest
    short = [(v, int(n)) for v, n in zip(levels[1:-1], counts[1:-1], strict=True) if n < MIN_SAMPLES]
    if short:  # g is 0 and 1 at the first and last level by definition: those may be dark or clipped
        raise ProjsynthError(
            f"level {short[0][0]}: only {short[0][1]} of {len(samples)} lit pixels are neither clipped nor "
            "black in every channel; set the exposure so that the white step does not clip"
        )
    g = np.tile((np.asarray(levels, np.float64) / 255) ** fallback, (3, 1)).T  # (K, 3)
    g, noise = _fit_at(samples, (samples > NEAR_END) & (samples < SATURATED - NEAR_END), g, fallback, MAX_STEPS)
    # within a few noise sigmas of either end, clipping has taken the samples that noise pushed past it, and
    # what is left is biased: near black an offset the model lacks, which varies against a_p and would
    # "identify" an exponent; the profile leaves both ends out, the curve the top one
    margin = max(NEAR_END, NOISE_SIGMAS * noise)
    clear = (samples > margin) & (samples < SATURATED - margin)
    profile, curves = {}, {}
    for e in EXPONENTS:  # each from the previous one's curve
        g, profile[e] = _fit_at(samples, clear, g, e, MAX_STEPS)
        curves[e] = g
    best = min(profile, key=profile.get)
    for e in _refinements(best):  # each from the nearest grid point's curve
        nearest = min(EXPONENTS, key=lambda x: abs(x - e))
        profile[e] = _fit_at(samples, clear, curves[nearest], e, MAX_STEPS)[1]
    interval = _interval(profile, len(samples))
    # a best exponent at the grid's end is no measurement: noise bends the profile towards one end
    identified = bool(
        interval[1] - interval[0] <= MAX_INTERVAL and EXPONENTS[0] < interval[0] <= interval[1] < EXPONENTS[-1]
    )
    exponent = float(min(profile, key=profile.get)) if identified else fallback
    # the curve from the samples near black too: the black step's pin g(0) = 0 to the pixels' offsets
    start = curves[min(EXPONENTS, key=lambda x: abs(x - exponent))]
    g, rms = _fit_at(samples, unclipped & (samples < SATURATED - margin), start, exponent, MAX_STEPS)
    points = _rising(levels, g.T)
    return Response(
        round(exponent, 3),
        projector_curve(levels, points),
        identified,
        interval,
        levels,
        points.astype(np.float32),
        float(255 * rms),
        len(samples),
    )


def _samples(levels: tuple[int, ...], photos: np.ndarray) -> np.ndarray:
    """``(P, K, 3)``: the photos at up to ``MAX_PIXELS`` lit pixels, after the checks of the photos as a whole."""
    contrast = photos[-1] - photos[0]  # (Hc, Wc, 3)
    median = float(np.median(contrast.mean(axis=2)))
    if median < MIN_CONTRAST:
        raise ProjsynthError(
            f"the photos of levels 0 and 255 barely differ (median {median:.1%} of full scale): the projector was "
            "off or hidden, or the exposure far too short or too long"
        )
    lit = contrast.min(axis=2) >= LIT_CONTRAST
    if lit.sum() < MIN_PIXELS:
        raise ProjsynthError(
            f"the projector brightens only {int(lit.sum())} camera pixels by {LIT_CONTRAST:.0%} of full scale in "
            f"every channel (need {MIN_PIXELS}); aim the camera at the projection, or lengthen the exposure"
        )
    clipped = float((photos[-1] >= SATURATED).any(axis=2)[lit].mean())
    if clipped > MAX_CLIPPED:
        raise ProjsynthError(
            f"the photo of level 255 is clipped on {clipped:.0%} of the lit pixels (at most {MAX_CLIPPED:.0%}): "
            "shorten the exposure until white is no longer clipped"
        )
    means = photos[:, lit].mean(axis=1).mean(axis=1)  # (K,)
    for k in np.flatnonzero(np.diff(means) < -0.5 / 255):
        raise ProjsynthError(
            f"the photo of level {levels[k + 1]} is darker than that of level {levels[k]}: are the photos in "
            "order, and were the exposure and the room's light fixed?"
        )
    ys, xs = np.nonzero(lit)
    pick = np.linspace(0, len(ys) - 1, min(len(ys), MAX_PIXELS)).round().astype(np.int64)
    return np.ascontiguousarray(photos[:, ys[pick], xs[pick]].transpose(1, 0, 2))


def _fit_at(c: np.ndarray, valid: np.ndarray, g: np.ndarray, exponent: float, steps: int) -> tuple:
    """Least squares in camera values of ``c`` ``(P, K, 3)`` for one camera exponent, from ``g`` ``(K, 3)``:
    up to ``steps`` Gauss-Newton steps, each solving every pixel's ``(o, a)`` given ``g`` and then the
    levels' ``g`` with the pixels' parameters eliminated (variable projection), halved until the residual
    falls. Returns the new ``g`` and the rms residual over the valid samples (full scale 1)."""
    g, valid = g.astype(np.float64), valid.astype(np.float32)
    # g(0) = 0 pins the pixels' offsets through the black step's samples only; without enough of them
    # (a dark room, near black left out), g -> b + (1 - b) g fits as well: the first level with samples
    # keeps its value instead, and the levels below it are left out
    first = int(np.argmax(valid.sum(axis=0).min(axis=1) >= MIN_SAMPLES))
    valid[:, :first] = 0
    free = np.arange(first + 1, g.shape[0] - 1)
    floor = SLOPE_FLOOR**exponent
    fit = _pixels(c, valid, np.maximum(c, SLOPE_FLOOR).astype(np.float64) ** exponent, g, exponent, floor)
    for _ in range(steps):
        o, a, w, t, m, rms = fit
        step = _level_step(t - o[:, None] - a[:, None] * g, w, a, g, m, free)
        for _ in range(STEP_HALVINGS):
            trial = g.copy()
            trial[free] += step
            again = _pixels(c, valid, o[:, None] + a[:, None] * trial, trial, exponent, floor)
            if again[-1] <= rms:
                g, fit = trial, again
                break
            step = step / 2
        if fit[-1] > rms * (1 - CONVERGED):  # no step lowered the residual by more than this: converged
            break
    return g, fit[-1]


def _pixels(c: np.ndarray, valid: np.ndarray, z: np.ndarray, g: np.ndarray, exponent: float, floor: float) -> tuple:
    """Every pixel's ``(o, a)`` for the curve ``g``, one Gauss-Newton step from the prediction ``z``:
    ``(o, a, w, t, m, rms)`` with the working weights ``w`` (0 where a pixel is not pinned down) and values
    ``t``, the per-pixel normal matrix ``m`` and the rms residual in camera values."""
    t, w = _working(c, valid, z, exponent, floor)
    o, a, ok, m = _per_pixel(t, w, g)
    used = valid * ok[:, None]
    shown = np.maximum(o[:, None] + a[:, None] * g, 0) ** (1 / exponent)
    rms = float(np.sqrt((used * (shown - c) ** 2).sum() / max(used.sum(), 1)))
    return o, a, w * ok[:, None], t, m, rms


def _level_step(r: np.ndarray, w: np.ndarray, a: np.ndarray, g: np.ndarray, m: tuple, free: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step ``(F, 3)`` of the ``free`` levels' ``g`` (``(K, 3)``) for residuals ``r``
    ``(P, K, 3)``, weights ``w`` and the pixels' ``(o, a)`` eliminated: per pixel the residual's sensitivity
    to ``g_j`` is ``-a e_j`` projected off ``span(1, g)``, so the normal matrix is
    ``sum_p a_p^2 (W_p - W_p B_p M_p^-1 B_p^T W_p)``."""
    s0, s1, s2, det = m  # (P, 3): the per-pixel normal matrix M = B^T W B of B = [1, g] and its determinant
    u0, u1 = w, w * g  # W B, column by column
    k2 = a**2 / det
    cross = _gram(u0, u1, k2 * s1)
    h = cross + cross.transpose(0, 2, 1) - _gram(u0, u0, k2 * s2) - _gram(u1, u1, k2 * s0)  # (3, K, K)
    h += ((a**2)[:, None] * w).sum(axis=0).T[:, :, None] * np.eye(g.shape[0])
    b = (a[:, None] * w * r).sum(axis=0).T  # (3, K)
    step = np.zeros((len(free), g.shape[1]))
    for ch in range(g.shape[1]):
        hc = h[ch][np.ix_(free, free)]
        damped = hc + DAMPING * np.diag(np.diag(hc))  # Levenberg-Marquardt: bounded along a flat direction
        step[:, ch] = np.linalg.solve(damped, b[ch][free])
    return step


def _working(c: np.ndarray, valid: np.ndarray, z: np.ndarray, exponent: float, floor: float) -> tuple:
    """Gauss-Newton's working values: linear light ``t`` and weights ``w`` such that a weighted least-squares
    step in linear light is one in camera values, around the prediction ``z``."""
    z = np.maximum(z, floor)
    shown = z ** (1 / exponent)
    slope = shown / (exponent * z)  # dF/dz
    return z + (c - shown) / slope, valid * slope**2


def _gram(x: np.ndarray, y: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``(3, K, K)``: ``sum_p weight[p, c] x[p, j, c] y[p, k, c]`` per channel ``c`` (one matrix product each)."""
    xw = np.ascontiguousarray((x * weight[:, None]).transpose(2, 1, 0))  # (3, K, P)
    return np.matmul(xw, np.ascontiguousarray(y.transpose(2, 0, 1)))


def _per_pixel(t: np.ndarray, w: np.ndarray, g: np.ndarray) -> tuple:
    """Weighted least squares of ``t ~ o + a g`` per pixel and channel: ``o``, ``a``, ``ok`` (where at least
    three samples of distinct levels pin it down) and the normal matrix's ``(s0, s1, s2, det)``."""
    s0, s1, s2 = w.sum(axis=1), (w * g).sum(axis=1), (w * g * g).sum(axis=1)
    t0, t1 = (w * t).sum(axis=1), (w * g * t).sum(axis=1)
    det = s0 * s2 - s1 * s1
    ok = (det > 1e-9 * np.maximum(s0 * s2, 1e-30)) & ((w > 0).sum(axis=1) >= 3)
    det = np.where(ok, det, 1)
    o, a = np.where(ok, (s2 * t0 - s1 * t1) / det, 0), np.where(ok, (s0 * t1 - s1 * t0) / det, 0)
    return o, a, ok, (s0, s1, s2, det)


def _refinements(best: float) -> list[float]:
    """Exponents around the grid's best, a quarter of the grid's step apart, up to the neighbours."""
    step = EXPONENTS[1] - EXPONENTS[0]
    around = (round(best + step * q / 4, 3) for q in (-3, -2, -1, 1, 2, 3))
    return [e for e in around if EXPONENTS[0] < e < EXPONENTS[-1]]


def _interval(profile: dict[float, float], pixels: int) -> tuple[float, float]:
    """The exponents that fit the photos as well as the best one: whose mean squared residual is within
    ``PROFILE_MARGIN / pixels`` of the best's, relatively (a likelihood-ratio bound counted per pixel)."""
    best = min(profile.values())
    good = [e for e, r in profile.items() if r**2 <= best**2 * (1 + PROFILE_MARGIN / pixels)]
    return float(min(good)), float(max(good))


def _rising(levels: tuple[int, ...], points: np.ndarray) -> np.ndarray:
    """``points`` ``(3, K)`` made non-decreasing in [0, 1]; a fall beyond ``FALL_TOLERANCE`` is refused."""
    for c, row in enumerate(points):
        for k in np.flatnonzero(np.diff(row) < -FALL_TOLERANCE):
            raise ProjsynthError(
                f"the projector's {'RGB'[c]} light falls from level {levels[k]} to {levels[k + 1]}: are the photos "
                "in order, and were the exposure and the room's light fixed?"
            )
    return np.maximum.accumulate(np.clip(points, 0, 1), axis=1)


def response_record(response: Response) -> dict:
    """The JSON of a response file (docs/format.md, "Response files")."""
    return {
        "format_version": RESPONSE_FORMAT,
        "generator": f"projsynth {__version__}",
        "camera": {
            "model": "power",
            "exponent": response.camera_exponent,
            "identified": response.identified,
            "interval": None if response.interval is None else list(response.interval),
        },
        "projector": {
            "levels": list(response.levels),
            "points": [[round(float(v), 6) for v in row] for row in response.points],
            "interpolation": INTERPOLATION,
        },
        "fit": {"pixels": response.pixels, "rms_dn": None if response.rms_dn is None else round(response.rms_dn, 4)},
    }


def read_response(path: Path) -> Response:
    """The curves of a response file written by ``projsynth response`` (or by hand, with its fields).

    Raises:
        ProjsynthError: naming the file: missing, unreadable, of another version, or with curves that are
            not rising from 0 at level 0 to 1 at level 255, or an exponent outside (0.5, 4).
    """
    path = Path(path)
    again = "fit it again with `projsynth response`"
    try:
        d = json.loads(path.read_text())
        if d["format_version"] != RESPONSE_FORMAT:
            raise ValueError(f"format {d['format_version']}")
        exponent = float(d["camera"]["exponent"])
        levels = tuple(d["projector"]["levels"])
        points = np.array(d["projector"]["points"], np.float64)
        interval = d["camera"].get("interval")
        interval = None if interval is None else (float(interval[0]), float(interval[1]))
        identified = bool(d["camera"].get("identified", True))
        fit = d.get("fit") or {}
        rms_dn, pixels = fit.get("rms_dn"), int(fit.get("pixels", 0))
    except FileNotFoundError:
        raise ProjsynthError(f"{path}: missing; --response is the file written by `projsynth response`") from None
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError) as e:
        raise ProjsynthError(f"{path}: not a response file ({e}); {again}") from None
    if not 0.5 < exponent < 4:
        raise ProjsynthError(f'{path}: "exponent" {exponent} is outside (0.5, 4); {again}')
    rising = all(type(v) is int for v in levels) and levels[:1] == (0,) and levels[-1:] == (255,)
    rising = rising and all(b > a for a, b in zip(levels, levels[1:], strict=False))
    shape_ok = points.shape == (3, len(levels)) and bool(np.isfinite(points).all())
    if not (rising and shape_ok and np.allclose(points[:, [0, -1]], [0, 1]) and (np.diff(points) >= 0).all()):
        raise ProjsynthError(
            f'{path}: "projector" must hold "levels" rising from 0 to 255 and three rows of "points" rising from '
            f"0 to 1 at them; {again}"
        )
    curve = projector_curve(levels, points)
    return Response(exponent, curve, identified, interval, levels, points.astype(np.float32), rms_dn, pixels)


def fit_folder(patterns_dir: Path, captures: Path, out: Path) -> str:
    """``projsynth response``: the photos in ``captures`` of the response set in ``patterns_dir`` (named as
    the patterns, as ``decode`` reads them) fitted into the JSON file ``out``; nothing is written when
    the fit is refused.

    Returns:
        A one-line summary for the user.
    """
    out, captures = Path(out), Path(captures)
    if out.suffix.lower() != ".json":
        raise ProjsynthError(f"--out {out}: the response is one JSON file; name it e.g. response.json")
    patterns = read_patterns(patterns_dir)
    if patterns.kind != "response":
        raise ProjsynthError(
            f"--patterns {patterns_dir}: a {patterns.kind} set; the response is measured from the grey levels of "
            "`projsynth patterns --kind response`"
        )
    inputs = folder_files("--captures", captures) + folder_files("--patterns", Path(patterns_dir))
    refuse_overwriting_inputs([("--out", out)], inputs)
    photos, files = load_captures(patterns, captures, load_rgb)
    try:
        response = fit_response(patterns.params["levels"], photos)
    except ProjsynthError as e:
        raise ProjsynthError(f"--captures {captures}: {e}") from None
    record = response_record(response)
    record["fit"].update({"camera_size": list(photos.shape[1:3]), "photos": [f.name for f in files]})
    write_atomic_all([(out, (json.dumps(record, indent=1) + "\n").encode())], make_parents=True)
    remove_stale_temporaries(out.parent, [out.name])
    return summary(response)


def summary(response: Response) -> str:
    """One line on a fitted response: the camera's exponent (or why it is assumed) and the fit's residual."""
    lo, hi = response.interval or (response.camera_exponent, response.camera_exponent)
    camera = (
        f"camera exponent {response.camera_exponent:.2f} (the photos allow {lo:.2f}-{hi:.2f})"
        if response.identified
        else f"camera exponent not identified by these photos (the room's light may be in one proportion to the "
        f"projector's everywhere): {response.camera_exponent:g} assumed"
    )
    return (
        f"{camera}; projector curves at {len(response.levels)} levels; residual {response.rms_dn:.2f} DN "
        f"over {response.pixels} pixels"
    )
