"""Projection surfaces and their exact first-hit ray casts.

Every surface lives in a local frame (x right, y down, z away from the projector) whose origin sits
on the surface; ``Surface.world_from_local`` places it in the world (= projector) frame. The surface
is oriented: its front side faces the projector (local -z). A ray "hits" a surface at the smallest
positive ``t`` where it meets the front side; anything else is a miss.

Kinds (parameters in world units, the projector-surface distance being about 1):
  plane                    z = 0
  cylinder_convex          near half of x^2 + (z - R)^2 = R^2   (bulges towards the projector)
  cylinder_concave         far half of  x^2 + (z + R)^2 = R^2   (a curved screen seen from inside)
  sphere_convex/_concave   the same with x^2 + y^2
  wave                     z = sum_i A_i sin(k_i . (x, y) + phi_i)
  bumps                    z = sum_i a_i exp(-|(x, y) - c_i|^2 / (2 s_i^2))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..utils.jit import jit

KINDS = ("plane", "cylinder_convex", "cylinder_concave", "sphere_convex", "sphere_concave", "wave", "bumps")
PLANE, CYLINDER_CONVEX, CYLINDER_CONCAVE, SPHERE_CONVEX, SPHERE_CONCAVE, WAVE, BUMPS = range(len(KINDS))
_HIT_TOL = 1e-9  # |g(t)| at convergence for height fields, in world units (~1e-6 px)
_MAX_SAFE_STEPS = 48  # rays still short of the root then (near-grazing) count as misses
_NEAR = 1e-5  # safe stepping hands over to Newton this close to the root (world units)


@dataclass(frozen=True)
class Surface:
    """A surface of one of :data:`KINDS`.

    ``params``: ``radius`` for quadrics; ``waves`` = [(amplitude, kx, ky, phase)] for wave;
    ``bumps`` = [(amplitude, cx, cy, sigma)] for bumps.
    """

    kind: str
    rotation: np.ndarray  # world_from_local rotation, (3, 3)
    origin: np.ndarray  # local origin in the world frame, (3,)
    params: dict = field(default_factory=dict)

    @cached_property
    def packed(self) -> tuple[tuple[float, ...], np.ndarray]:
        """The surface as the kernels take it: ``(geometry, terms)`` (see ``_pack``)."""
        return _pack(self.kind, self.rotation, self.origin, self.params)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "rotation": self.rotation.tolist(),
            "origin": self.origin.tolist(),
            **self.params,
        }


def intersect(surface: Surface, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First front-side hit of rays ``o + t d`` (world frame, ``d`` unit ``(3, N)``, ``o`` ``(3, N)``
    or one shared origin ``(3, 1)``).

    Returns:
        ``(t, hit)``: distance along each ray (inf where missed) and the hit mask.
    """
    o, d = _rays(o, d)
    t = _intersect_many(*surface.packed, o, d)
    return t, np.isfinite(t)


def _rays(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    o = np.ascontiguousarray(o, np.float64)
    d = np.ascontiguousarray(d, np.float64)
    if o.ndim != 2 or d.ndim != 2 or o.shape[0] != 3 or d.shape[0] != 3 or o.shape[1] not in (1, d.shape[1]):
        raise ValueError(f"rays need origins (3, 1) or (3, N) and directions (3, N), got {o.shape} and {d.shape}")
    return o, d


def _pack(kind: str, rotation: np.ndarray, origin: np.ndarray, params: dict) -> tuple[tuple[float, ...], np.ndarray]:
    if kind not in KINDS:
        raise ValueError(f"unknown surface kind {kind!r}")
    code = KINDS.index(kind)
    radius, terms, bound, slope, curvature = 0.0, np.zeros((0, 4)), 0.0, 0.0, 0.0
    if code in (CYLINDER_CONVEX, CYLINDER_CONCAVE, SPHERE_CONVEX, SPHERE_CONCAVE):
        radius = float(params["radius"])
    elif code == WAVE:  # bounds of |h|, |grad h| and of h's second derivative along any unit direction
        terms = np.asarray(params["waves"], dtype=np.float64).reshape(-1, 4)
        amp, kx, ky, _ = terms.T
        bound, slope = float(np.abs(amp).sum()), float((np.abs(amp) * np.hypot(kx, ky)).sum())
        curvature = float((np.abs(amp) * (kx * kx + ky * ky)).sum())
    elif code == BUMPS:  # a Gaussian's slope peaks at e^-0.5 / s, its curvature at 1 / s^2 (the centre)
        terms = np.asarray(params["bumps"], dtype=np.float64).reshape(-1, 4)
        amp, _, _, sigma = terms.T
        bound, slope = float(np.abs(amp).sum()), float((np.abs(amp) / sigma).sum() * np.exp(-0.5))
        curvature = float((np.abs(amp) / (sigma * sigma)).sum())
    geometry = (
        code,
        *np.asarray(rotation, np.float64).ravel(),
        *np.asarray(origin, np.float64),
        radius,
        bound,
        slope,
        curvature,
    )
    return tuple(float(x) for x in geometry), np.ascontiguousarray(terms)


# Per-ray kernels (numba). A packed surface is the pair made by _pack: a tuple of floats ``g`` (kind
# code, world_from_local rotation row-major, origin, radius, height-field bound, slope and curvature
# bounds), passed by value, and the (M, 4) height-field ``terms``.


@jit(inline=True)
def _to_local(g, ox, oy, oz, dx, dy, dz):  # noqa: ANN001, ANN202
    px, py, pz = ox - g[10], oy - g[11], oz - g[12]  # R^T (o - origin), R^T d; R[i, j] = g[1 + 3 i + j]
    return (
        g[1] * px + g[4] * py + g[7] * pz,
        g[2] * px + g[5] * py + g[8] * pz,
        g[3] * px + g[6] * py + g[9] * pz,
        g[1] * dx + g[4] * dy + g[7] * dz,
        g[2] * dx + g[5] * dy + g[8] * dz,
        g[3] * dx + g[6] * dy + g[9] * dz,
    )


@jit(inline=True)
def hit1(g, terms, ox, oy, oz, dx, dy, dz, t0):  # noqa: ANN001, ANN201
    """Distance to the first front-side hit of one world-frame ray (``inf`` when it misses).

    ``t0``: a guess (the neighbouring ray's distance, or nan). Height fields start their bracketed
    Newton there when it lies inside the bracket; the root, unique for such rays, does not depend on it
    beyond the convergence tolerance (1e-10 world units, about 1e-7 px).
    """
    ox, oy, oz, dx, dy, dz = _to_local(g, ox, oy, oz, dx, dy, dz)
    kind = g[0]
    if kind == PLANE:
        t = -oz / dz if dz > 1e-12 else np.inf
        return t if t > 0 else np.inf
    if kind == WAVE or kind == BUMPS:
        return _heightfield(kind, terms, g[14], g[15], g[16], ox, oy, oz, dx, dy, dz, t0)
    return _quadric(kind, g[13], ox, oy, oz, dx, dy, dz)


@jit(inline=True)
def single1(g, ox, oy, oz, dx, dy, dz):  # noqa: ANN001, ANN201
    """True when one world-frame ray provably meets the surface at most once, so nothing hides its hit.

    Planes when the eye is in front of them; height fields when the ray is steeper than the surface's
    maximum slope; concave quadrics when the ray's origin is inside them; otherwise the caller casts.
    """
    ox, oy, oz, dx, dy, dz = _to_local(g, ox, oy, oz, dx, dy, dz)
    kind = g[0]
    if kind == PLANE:  # a single crossing, if the eye is on the front side at all
        return oz < 0
    if kind == WAVE or kind == BUMPS:
        return dz > g[15] * np.sqrt(dx * dx + dy * dy) * 1.0001
    if kind == CYLINDER_CONCAVE or kind == SPHERE_CONCAVE:
        # seen from inside the full quadric, its inner surface never hides itself
        rz = oz + g[13]
        r2 = ox * ox + rz * rz + (oy * oy if kind == SPHERE_CONCAVE else 0.0)
        return r2 < g[13] * g[13]
    return False


@jit(inline=True)
def convex_sees1(g, ex, ey, ez, x, y, z):  # noqa: ANN001, ANN201
    """For a surface point ``X`` of a convex cylinder or sphere: whether the eye ``e`` sees it, without a cast.

    The full cylinder or sphere is a convex body and the surface a part of its boundary, so the segment
    from the eye meets the boundary first at ``X`` exactly when it enters the body there, that is when
    it runs against the outward normal at ``X`` (the front side). An eye inside the body sees nothing.
    """
    ex, ey, ez, dx, dy, dz = _to_local(g, ex, ey, ez, x - ex, y - ey, z - ez)
    px, py, pz = ex + dx, ey + dy, ez + dz  # X in the local frame; the centre is (0, y or 0, radius)
    return dx * px + (dy * py if g[0] == SPHERE_CONVEX else 0.0) + dz * (pz - g[13]) < 0


@jit(inline=True)
def never_hidden1(g, ex, ey, ez):  # noqa: ANN001, ANN201
    """True when every ray from the eye meets the surface at most once, whatever its direction: a plane
    seen from its front side, a concave quadric seen from inside."""
    kind = g[0]
    fixed = kind == PLANE or kind == CYLINDER_CONCAVE or kind == SPHERE_CONCAVE  # direction plays no part
    return fixed and single1(g, ex, ey, ez, 0.0, 0.0, 1.0)


@jit
def _quadric(kind, radius, ox, oy, oz, dx, dy, dz):  # noqa: ANN001, ANN202
    convex = kind == CYLINDER_CONVEX or kind == SPHERE_CONVEX
    ocz = oz - (radius if convex else -radius)  # relative to the centre; cylinders' axis is local y
    sphere = kind == SPHERE_CONVEX or kind == SPHERE_CONCAVE
    a = dx * dx + dz * dz + (dy * dy if sphere else 0.0)
    b = ox * dx + ocz * dz + (oy * dy if sphere else 0.0)  # half of the usual b
    c = ox * ox + ocz * ocz + (oy * oy if sphere else 0.0) - radius * radius
    disc = b * b - a * c
    if not (disc >= 0 and a > 1e-15):
        return np.inf
    # The roots are q / a and c / q (numerically stable). Only one can be a front-side hit: on a convex
    # surface the entry into the body (the smaller root), on a concave one the exit (the larger).
    q = -(b + np.copysign(np.sqrt(disc), b))
    t = q / a if (q < 0) == convex else c / q  # q / a - c / q = (q^2 - a c) / (a q) has the sign of q
    if not np.isfinite(t):
        return np.inf
    # at o + t d: (d . outward normal) = b + t a up to a positive factor, height = oc_z + t d_z;
    # the front side of a concave surface is its inside
    dot = b + t * a
    z = ocz + t * dz
    facing = dot < 0 if convex else dot > 0
    on_half = z <= 0 if convex else z >= 0
    return t if t > 1e-9 and on_half and facing else np.inf


@jit(inline=True)
def _field(kind, terms, x, y):  # noqa: ANN001, ANN202
    """Height and gradient ``(h, h_x, h_y)`` of a wave or bumps field at local ``(x, y)``."""
    h = hx = hy = 0.0
    for i in range(terms.shape[0]):
        a, p, q, r = terms[i, 0], terms[i, 1], terms[i, 2], terms[i, 3]
        if kind == WAVE:  # a sin(kx x + ky y + phase): p, q = kx, ky; r = phase
            arg = p * x + q * y + r
            h += a * np.sin(arg)
            c = a * np.cos(arg)
            hx += p * c
            hy += q * c
        else:  # a exp(-|(x, y) - (cx, cy)|^2 / (2 s^2)): p, q = cx, cy; r = s
            ex, ey = x - p, y - q
            e = a * np.exp((ex * ex + ey * ey) * (-0.5 / (r * r)))
            h += e
            hx -= ex * e / (r * r)
            hy -= ey * e / (r * r)
    return h, hx, hy


@jit(inline=True)
def _g(kind, terms, ox, oy, oz, dx, dy, dz, t):  # noqa: ANN001, ANN202
    """``g(t) = o_z + t d_z - h(o_xy + t d_xy)`` and ``g'(t)``."""
    h, hx, hy = _field(kind, terms, ox + t * dx, oy + t * dy)
    return oz + t * dz - h, dz - hx * dx - hy * dy


@jit(inline=True)
def _heightfield(kind, terms, bound, slope, curvature, ox, oy, oz, dx, dy, dz, t0):  # noqa: ANN001, ANN202
    """First root of ``g`` inside the slab ``|z| <= bound``.

    Rays steeper than the surface (``d_z > slope * |d_xy|``) meet it exactly once: bracketed Newton.
    There ``g' >= m = d_z - slope |d_xy| > 0`` and ``|g''| <= curvature |d_xy|^2``, so a Newton step from
    ``t`` lands within ``curvature |d_xy|^2 g(t)^2 / (2 m^3)`` of the root: when that bound already
    meets the tolerance the step is returned without evaluating the field again (from a neighbouring
    ray's guess, one field evaluation per ray instead of two).
    The others march with steps that can never pass the first root (the longer of the Lipschitz step
    ``-g / (d_z + slope |d_xy|)`` and the curvature step, see the loop), then Newton polishes; rays that
    do not converge (near-grazing) count as misses.
    """
    if not (dz > 1e-9 and oz < -bound):  # the viewer must be in front of the slab, looking in
        return np.inf
    idz = 1.0 / dz
    lo, hi = (-bound - oz) * idz, (bound - oz) * idz
    dxy = np.sqrt(dx * dx + dy * dy)  # (np.hypot guards against overflow, at twice the cost)
    if dz > slope * dxy * 1.0001:  # certified single crossing, as in single1
        a, b = lo, hi  # g(a) <= 0 <= g(b)
        t = t0 if a <= t0 <= b else min(max(-oz * idz, a), b)  # the guess, else the mean plane z = 0
        m = dz - slope * dxy
        newton_gain = 0.5 * curvature * dxy * dxy / (m * m * m) * (dz + slope * dxy)  # |g| after / g^2 before
        for _ in range(60):
            g, gp = _g(kind, terms, ox, oy, oz, dx, dy, dz, t)
            if abs(g) < _HIT_TOL:
                return t
            if g < 0:
                a = t
            elif g > 0:
                b = t
            tn = t - g / gp
            if a <= tn <= b and newton_gain * g * g < 0.5 * _HIT_TOL:
                return tn
            t = tn if a <= tn <= b else 0.5 * (a + b)
        return np.inf
    lipschitz, bend = dz + slope * dxy, curvature * dxy * dxy  # |g'| <= lipschitz, |g''| <= bend
    t = lo
    for step in range(_MAX_SAFE_STEPS):
        g, gp = _g(kind, terms, ox, oy, oz, dx, dy, dz, t)
        if g > -_NEAR:
            break
        if step == _MAX_SAFE_STEPS - 1:
            return np.inf
        # Two safe steps, the longer wins: g stays below 0 for s < -g / lipschitz, and below the
        # parabola g + g' s + bend s^2 / 2 until its first root, which near a simple root is Newton's
        # step (the form without cancellation for either sign of g'; bend = 0, g' <= 0: no root, inf).
        root = np.sqrt(gp * gp - 2.0 * bend * g)
        curved = -2.0 * g / (gp + root) if gp >= 0 else (root - gp) / bend
        t += max(-g / lipschitz, curved if np.isfinite(curved) else 0.0)
    for _ in range(4):  # within _NEAR of the first root only a tangent ray could reach a later one
        g, gp = _g(kind, terms, ox, oy, oz, dx, dy, dz, t)
        if gp > 1e-12:
            t -= g / gp
    g, _ = _g(kind, terms, ox, oy, oz, dx, dy, dz, t)
    return t if abs(g) < _HIT_TOL and t <= hi else np.inf


@jit
def _intersect_many(g, terms, o, d):  # noqa: ANN001, ANN202
    t = np.empty(d.shape[1])
    shared = o.shape[1] == 1
    for i in range(d.shape[1]):
        j = 0 if shared else i
        t[i] = hit1(g, terms, o[0, j], o[1, j], o[2, j], d[0, i], d[1, i], d[2, i], np.nan)
    return t
