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

import numpy as np

KINDS = (
    "plane",
    "cylinder_convex",
    "cylinder_concave",
    "sphere_convex",
    "sphere_concave",
    "wave",
    "bumps",
)
_HIT_TOL = 1e-10  # |g(t)| at convergence for height fields, in world units (~1e-7 px)
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

    def to_local(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World ``(3, N)`` ray origins and directions in the local frame (``o`` may be ``(3, 1)``)."""
        rt = self.rotation.T
        return rt @ (o - self.origin[:, None]), rt @ d

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "rotation": self.rotation.tolist(),
            "origin": self.origin.tolist(),
            **self.params,
        }


def single_crossing(surface: Surface, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """True for rays ``(3, N)`` that provably meet the surface at most once (so nothing hides it).

    Planes when the eye is in front of them; height fields when the ray is steeper than the surface's
    maximum slope; concave quadrics when the shared origin ``o`` ``(3, 1)`` is inside them; otherwise
    the caller casts.
    """
    if surface.kind == "plane":  # a single crossing, if the eye is on the front side at all
        ol, _ = surface.to_local(o, d[:, :1])
        return np.broadcast_to(ol[2] < 0, (d.shape[1],)).copy()
    if surface.kind in _HEIGHTFIELDS:
        _, dl = surface.to_local(o, d)
        return dl[2] > _HEIGHTFIELDS[surface.kind](surface.params).slope * np.hypot(dl[0], dl[1]) * 1.0001
    if surface.kind.endswith("concave") and o.shape[1] == 1:
        # seen from inside the full quadric, its inner surface never hides itself
        radius = surface.params["radius"]
        ol, _ = surface.to_local(o, d[:, :1])
        rel = ol[:, 0] - np.array([0.0, 0.0, -radius])
        inside = (rel[0] ** 2 + rel[2] ** 2 + (rel[1] ** 2 if surface.kind.startswith("sphere") else 0.0)) < radius**2
        return np.full(d.shape[1], bool(inside))
    return np.zeros(d.shape[1], bool)


def intersect(surface: Surface, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First front-side hit of rays ``o + t d`` (world frame, ``d`` unit ``(3, N)``, ``o`` ``(3, N)``
    or one shared origin ``(3, 1)``).

    Returns:
        ``(t, hit)``: distance along each ray (inf where missed) and the hit mask.
    """
    ol, dl = surface.to_local(o, d)
    if surface.kind == "plane":
        t = _plane(ol, dl)
    elif surface.kind.startswith(("cylinder", "sphere")):
        t = _quadric(surface.kind, surface.params["radius"], ol, dl)
    elif surface.kind in ("wave", "bumps"):
        t = _heightfield(_HEIGHTFIELDS[surface.kind](surface.params), ol, dl)
    else:
        raise ValueError(f"unknown surface kind {surface.kind!r}")
    hit = np.isfinite(t)
    return t, hit


def _plane(o: np.ndarray, d: np.ndarray) -> np.ndarray:
    dz = d[2]
    front = dz > 1e-12
    t = np.where(front, -o[2] / np.where(front, dz, 1.0), np.inf)
    return np.where(t > 0, t, np.inf)


def _quadric(kind: str, radius: float, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    convex = kind.endswith("convex")
    centre_z = radius if convex else -radius
    axes = [0, 2] if kind.startswith("cylinder") else [0, 1, 2]  # cylinder axis along local y
    oc = o - np.array([0.0, 0.0, centre_z])[:, None]  # relative to the centre
    oa, da = oc[axes], d[axes]
    a = (da * da).sum(0)
    b = (oa * da).sum(0)  # half of the usual b
    c = (oa * oa).sum(0) - radius * radius
    disc = b * b - a * c
    real = (disc >= 0) & (a > 1e-15)
    sq = np.sqrt(np.where(real, disc, 0.0))
    q = -(b + np.copysign(sq, b))  # numerically stable pair of roots: q / a and c / q
    with np.errstate(divide="ignore", invalid="ignore"):
        r0, r1 = q / a, c / q
    r0 = np.where(real & np.isfinite(r0), r0, np.inf)
    r1 = np.where(real & np.isfinite(r1), r1, np.inf)
    best = np.full(d.shape[1], np.inf)
    for t in (np.minimum(r0, r1), np.maximum(r0, r1)):  # take the first root on the front side
        # at o + t d: (d . outward normal) = b + t a up to a positive factor, height = oc_z + t d_z;
        # the front side of a concave surface is its inside
        dot = b + t * a
        facing = dot < 0 if convex else dot > 0
        z = oc[2] + t * d[2]
        on_half = z <= 0 if convex else z >= 0
        ok = np.isfinite(t) & (t > 1e-9) & on_half & facing & np.isinf(best)
        best = np.where(ok, t, best)
    return best


class _Wave:
    def __init__(self, params: dict):
        w = np.asarray(params["waves"], dtype=np.float64).reshape(-1, 4)
        self.amp, self.kx, self.ky, self.phase = w.T
        self.bound = float(np.abs(self.amp).sum())
        self.slope = float((np.abs(self.amp) * np.hypot(self.kx, self.ky)).sum())

    def __call__(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = np.zeros_like(x)
        hx = np.zeros_like(x)
        hy = np.zeros_like(x)
        for a, kx, ky, ph in zip(self.amp, self.kx, self.ky, self.phase, strict=True):
            arg = kx * x + ky * y + ph
            h += a * np.sin(arg)
            c = a * np.cos(arg)
            hx += kx * c
            hy += ky * c
        return h, hx, hy


class _Bumps:
    def __init__(self, params: dict):
        b = np.asarray(params["bumps"], dtype=np.float64).reshape(-1, 4)
        self.amp, self.cx, self.cy, self.sigma = b.T
        self.bound = float(np.abs(self.amp).sum())
        self.slope = float((np.abs(self.amp) / self.sigma).sum() * np.exp(-0.5))

    def __call__(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = np.zeros_like(x)
        hx = np.zeros_like(x)
        hy = np.zeros_like(x)
        for a, cx, cy, s in zip(self.amp, self.cx, self.cy, self.sigma, strict=True):
            dx, dy = x - cx, y - cy
            e = a * np.exp((dx * dx + dy * dy) * (-0.5 / (s * s)))
            h += e
            hx -= dx * e / (s * s)
            hy -= dy * e / (s * s)
        return h, hx, hy


_HEIGHTFIELDS = {"wave": _Wave, "bumps": _Bumps}


def _heightfield(field_: _Wave | _Bumps, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """First root of ``g(t) = o_z + t d_z - h(o_xy + t d_xy)`` inside the slab ``|z| <= bound``.

    Rays whose slope is steeper than the surface's (``d_z > slope * |d_xy|``) meet it exactly once:
    bracketed Newton. The others march with Lipschitz-safe steps ``t += -g / (d_z + slope |d_xy|)``,
    which can never pass the first root, and are dropped (miss) if they do not converge.
    """
    n = d.shape[1]
    o = np.broadcast_to(o, d.shape)
    t_out = np.full(n, np.inf)
    dz = d[2]
    dxy = np.hypot(d[0], d[1])
    usable = (dz > 1e-9) & (o[2] < -field_.bound)  # viewer in front of the slab, looking in
    lo = np.where(usable, (-field_.bound - o[2]) / np.where(usable, dz, 1.0), 0.0)
    hi = np.where(usable, (field_.bound - o[2]) / np.where(usable, dz, 1.0), 0.0)
    certified = usable & (dz > field_.slope * dxy * 1.0001)  # as in single_crossing

    def g_and_slope(idx: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx, dy = d[0, idx], d[1, idx]
        h, hx, hy = field_(o[0, idx] + t * dx, o[1, idx] + t * dy)
        return o[2, idx] + t * dz[idx] - h, dz[idx] - hx * dx - hy * dy

    # Certified rays: Newton inside the bracket [a, b] (g(a) <= 0 <= g(b)), bisecting when a step
    # leaves it; converged rays leave the active set.
    idx = np.nonzero(certified)[0]
    a, b = lo[idx], hi[idx]
    t = np.clip(-o[2, idx] / dz[idx], a, b)  # start at the mean plane z = 0
    for _ in range(60):
        if idx.size == 0:
            break
        g, gp = g_and_slope(idx, t)
        done = np.abs(g) < _HIT_TOL
        t_out[idx[done]] = t[done]
        keep = ~done
        idx, t, g, gp = idx[keep], t[keep], g[keep], gp[keep]
        a = np.where(g < 0, t, a[keep])
        b = np.where(g > 0, t, b[keep])
        tn = t - g / gp
        t = np.where((tn >= a) & (tn <= b), tn, 0.5 * (a + b))

    # Other rays: Lipschitz-safe steps approach the first root from below and never pass it; once
    # within _NEAR of it, Newton polishes (only a tangent ray could then reach a later root).
    idx = np.nonzero(usable & ~certified)[0]
    if idx.size:
        lipschitz = dz[idx] + field_.slope * dxy[idx]
        t = lo[idx]
        for _ in range(_MAX_SAFE_STEPS):
            g, _ = g_and_slope(idx, t)
            near = g > -_NEAR
            if near.all():
                break
            t = np.where(near, t, t - g / lipschitz)
        near = g > -_NEAR
        idx, t = idx[near], t[near]
        for _ in range(4):
            g, gp = g_and_slope(idx, t)
            t = t - g / np.where(gp > 1e-12, gp, np.inf)
        g, _ = g_and_slope(idx, t)
        t_out[idx] = np.where((np.abs(g) < _HIT_TOL) & (t <= hi[idx]), t, np.inf)
    return t_out
