"""Build a projector-camera :class:`~projsynth.sim.scene.Scene` from a configuration's drawn parameters.

Units: the projector's optical axis meets the surface at distance 1 (the local origin of the
surface). Angles in the table are degrees; everything here is radians. Pixel-valued ranges
(``aim_px``, ``principal_jitter_px``) are for a 512-px-wide frame and scale with the width, so a
configuration means the same geometry, and the same flow relative to the image, at any ``--size``.
"""

from __future__ import annotations

import numpy as np

from ..utils.ranges import draw
from .lens import Lens
from .scene import Scene, look_at, rotation_about
from .surface import Surface

REFERENCE_WIDTH = 512


def make_scene(
    family: str,
    ranges: dict,
    rng: np.random.Generator,
    size: tuple[int, int],
    camera_size: tuple[int, int] | None = None,
) -> tuple[Scene, dict]:
    """Draw a scene of ``family`` inside ``ranges`` with ``rng``.

    Args:
        size: the projector's frame ``(H, W)``.
        camera_size: the camera's frame ``(H, W)``; None: the projector's. The camera keeps its field
            of view: its focal length, principal point and aim offset scale with ``W_cam / W``, so a
            larger frame sees the same view with more pixels (the draws do not depend on it).

    Returns:
        ``(scene, params)``: the scene and every drawn value (ranges' draws plus the directions,
        signs and phases drawn here), JSON-serialisable.
    """
    height, width = size
    g = draw(rng, ranges)
    px = width / REFERENCE_WIDTH  # pixel-valued ranges are given for 512-px-wide frames
    # Directions and signs are drawn after the ranges, always in this order.
    extra = {
        "baseline_azimuth": float(rng.uniform(0, 2 * np.pi)),
        "aim_azimuth": float(rng.uniform(0, 2 * np.pi)),
        "roll_sign": _sign(rng),
        "tilt_azimuth": float(rng.uniform(0, 2 * np.pi)),
        "axis_angle": float(rng.uniform(0, np.pi)),
        "principal_azimuth": float(rng.uniform(0, 2 * np.pi)),
        "distortion_sign": _sign(rng),
    }
    f = 0.5 * width / np.tan(np.radians(g["fov_deg"]) / 2)
    jitter = g["principal_jitter_px"] * px
    jx, jy = jitter * np.cos(extra["principal_azimuth"]), jitter * np.sin(extra["principal_azimuth"])
    cx, cy = (width - 1) / 2, (height - 1) / 2
    proj_dist = cam_dist = (0.0,) * 5
    if family == "lens":
        s = extra["distortion_sign"]
        p_ang = rng.uniform(0, 2 * np.pi)
        cam_dist = (s * g["cam_k1"], s * g["cam_k2"], g["cam_p"] * np.cos(p_ang), g["cam_p"] * np.sin(p_ang), 0.0)
        proj_dist = (-s * g["proj_k1"], 0.0, 0.0, 0.0, 0.0)
        extra["tangential_angle"] = float(p_ang)
    projector = Lens(f, f, cx + jx, cy + jy, tuple(map(float, proj_dist)), width, height)
    cam_h, cam_w = camera_size or size
    k = cam_w / width  # camera pixels per projector pixel of the same view
    fc = f * g["fov_ratio"] * k
    camera = Lens(fc, fc, (cam_w - 1) / 2 - jx * k, (cam_h - 1) / 2 - jy * k, tuple(map(float, cam_dist)), cam_w, cam_h)

    target = np.array([0.0, 0.0, 1.0])
    b_axis = np.array([np.cos(extra["baseline_azimuth"]), np.sin(extra["baseline_azimuth"]), 0.0])
    C = target + g["distance_ratio"] * (rotation_about(b_axis, np.radians(g["baseline_deg"])) @ -target)
    aim_px = g["aim_px"] * px * k
    aim = (aim_px * np.cos(extra["aim_azimuth"]), aim_px * np.sin(extra["aim_azimuth"]))
    R = look_at(C, target, aim, extra["roll_sign"] * np.radians(g["roll_deg"]), camera)

    t_axis = np.array([np.cos(extra["tilt_azimuth"]), np.sin(extra["tilt_azimuth"]), 0.0])
    rot = rotation_about(t_axis, np.radians(g["tilt_deg"])) @ rotation_about(
        np.array([0.0, 0.0, 1.0]), extra["axis_angle"]
    )
    surface = Surface(_kind(family), rot, target, _shape_params(family, g, rng, extra))
    return Scene(projector, camera, R, C, surface), {**g, **extra}


def _sign(rng: np.random.Generator) -> float:
    return float(rng.choice([-1.0, 1.0]))


def _kind(family: str) -> str:
    return "plane" if family in ("planar", "lens") else family


def _shape_params(family: str, g: dict, rng: np.random.Generator, extra: dict) -> dict:
    if family.startswith(("cylinder", "sphere")):
        return {"radius": 1.0 / max(g["curvature"], 1e-3)}
    if family == "wave":
        waves = []
        for i in range(int(round(g["wave_count"]))):
            ang, phase = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
            k = 2 * np.pi * g["wave_freq"] * (1.0 if i == 0 else rng.uniform(1.3, 2.2))
            amp = g["wave_amp"] * (1.0 if i == 0 else 0.35)
            waves.append([amp, k * np.cos(ang), k * np.sin(ang), phase])
        extra["waves"] = waves
        return {"waves": waves}
    if family == "bumps":
        bumps = []
        for _ in range(int(round(g["bump_count"]))):
            amp = g["bump_amp"] * rng.uniform(0.5, 1.0) * rng.choice([-1.0, 1.0])
            bumps.append(
                [amp, rng.uniform(-0.45, 0.45), rng.uniform(-0.35, 0.35), g["bump_sigma"] * rng.uniform(0.7, 1.3)]
            )
        bumps = [[float(v) for v in b] for b in bumps]
        extra["bumps"] = bumps
        return {"bumps": bumps}
    return {}
