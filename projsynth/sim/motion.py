"""Moving-rig sequences: a seeded projector trajectory and the scene of each frame.

The projector flies (it hangs under the drone); the camera stays on its tripod and the surface stays
where it is. A sequence's scene (:func:`projsynth.sim.rig.make_scene`) is the rig at time 0; frame ``f``
is the same rig at ``t = f / FRAME_RATE_HZ`` with the projector moved by the trajectory's pose
``(rotation, centre)`` relative to where it was at time 0, so every frame's flow is again an exact ray
cast (:func:`moved_scene`). Every preset starts at that pose: frame 0 is the sequence's scene itself.

Units: world distances are in units of the projector-surface distance, taken as ``DISTANCE_M``
(3 m), so 1 cm is ``CM`` world units; angles in degrees. The presets and their bounds (checked by the
tests, at every time):

* ``hover``: slow drift, every axis a sum of two sinusoids of 0.2-0.8 Hz; translation at most 6 cm and
  rotation at most 1.2 deg per axis.
* ``gust``: a sudden displacement and its recovery, ``peak * s e^(1 - s)`` with ``s = (t - onset) / tau``
  (tau 30-100 ms; onset in the first half of the sequence): translation at most 10 cm (mostly
  sideways), rotation at most 3 deg.
* ``vibration``: rotation only, at the rotor frequency (80-200 Hz) plus its second harmonic: at most
  0.39 deg per axis. Frames are exposed for ``EXPOSURE_S`` (1/120 s): the photo is the mean of
  ``SUBFRAMES`` photos at poses spread evenly over the exposure (motion blur); the ground truth is the
  flow at mid-exposure.
* ``orbit``: a slow arc around the surface's aim point (distance 1) about an axis across the
  projector's view, 5-15 deg/s, the projector keeping its aim: arc angle at most 15 deg/s x t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene, rotation_about
from .surface import Surface

MOTIONS = ("hover", "gust", "vibration", "orbit")
FRAME_RATE_HZ = 30.0
DISTANCE_M = 3.0  # the projector-surface distance a world unit stands for
CM = 0.01 / DISTANCE_M  # world units per centimetre
EXPOSURE_S = 1 / 120  # vibration frames only; the other presets move too little within an exposure
SUBFRAMES = 5
TARGET = np.array([0.0, 0.0, 1.0])  # where the projector's axis meets the surface (rig.make_scene)
# per-preset bounds of the pose at any time: (translation cm, rotation deg) per axis (``None``: see above)
BOUNDS = {"hover": (6.0, 1.2), "gust": (10.0, 3.0), "vibration": (0.0, 0.39)}
ORBIT_RATE_DEG_S = (5.0, 15.0)


@dataclass(frozen=True)
class Trajectory:
    """A preset with its drawn values (``params``, JSON-serialisable)."""

    preset: str
    params: dict

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The projector's pose at time ``t`` (s) relative to time 0.

        Returns:
            ``(rotation, centre)``: the rotation ``base_from_moved`` (3, 3) and the moved projector's
            centre (3,), in world units of the sequence's scene (the projector frame at time 0).
        """
        p = self.params
        if self.preset == "orbit":
            theta = np.radians(p["rate_deg_s"] * t)
            rot = rotation_about(np.array(p["axis"]), theta)
            return rot, TARGET - rot @ TARGET
        if self.preset == "hover":
            d = _sines(p["amp"], p["freq_hz"], p["phase"], t)  # [6]: translation cm, rotation deg
        elif self.preset == "gust":
            s = (t - p["onset_s"]) / p["tau_s"]
            g = s * np.exp(1 - s) if s > 0 else 0.0  # peaks at 1 when s = 1
            d = g * np.concatenate([np.array(p["translation_cm"]), np.array(p["rotation_deg"])])
        elif self.preset == "vibration":
            f = p["freq_hz"]
            rot = _sines(p["amp"], [[f, 2 * f]] * 3, p["phase"], t)
            d = np.concatenate([np.zeros(3), rot])
        else:
            raise ValueError(f"unknown motion {self.preset!r}")
        return _rotation_deg(d[3:]), d[:3] * CM

    def exposure(self) -> tuple[float, ...]:
        """Offsets (s) from a frame's time of the poses its photo averages (one: no motion blur)."""
        if self.preset != "vibration":
            return (0.0,)
        return tuple(float(v) for v in np.linspace(-EXPOSURE_S / 2, EXPOSURE_S / 2, SUBFRAMES))

    def describe(self, t: float) -> dict:
        """The ``motion`` parameters of the frame at ``t``: preset, time, the pose as a rotation vector
        (deg) and a translation (cm), the exposure and the drawn trajectory."""
        rot, centre = self.pose(t)
        offsets = self.exposure()
        return {
            "preset": self.preset,
            "frame_rate_hz": FRAME_RATE_HZ,
            "time_s": t,
            "rotation_deg": [float(v) for v in np.degrees(rotation_vector(rot))],
            "translation_cm": [float(v) for v in centre / CM],
            "exposure_s": offsets[-1] - offsets[0],
            "subframes": len(offsets),
            "trajectory": self.params,
        }


def draw_trajectory(preset: str, frames: int, rng: np.random.Generator) -> Trajectory:
    """Draw a trajectory of ``preset`` (one of ``MOTIONS``) for a sequence of ``frames`` frames."""
    if preset == "hover":
        amp = np.concatenate([rng.uniform(0.5, 1.5, (3, 2)), rng.uniform(0.1, 0.3, (3, 2))])  # cm, deg
        params = {"amp": amp, "freq_hz": rng.uniform(0.2, 0.8, (6, 2)), "phase": rng.uniform(0, 2 * np.pi, (6, 2))}
    elif preset == "gust":
        direction = rng.normal(size=3) * np.array([1.0, 1.0, 0.3])  # wind pushes the drone mostly sideways
        axis = rng.normal(size=3)
        duration = (frames - 1) / FRAME_RATE_HZ
        params = {
            "onset_s": rng.uniform(0, duration / 2),
            "tau_s": rng.uniform(0.03, 0.1),
            "translation_cm": rng.uniform(3, 10) * direction / np.linalg.norm(direction),
            "rotation_deg": rng.uniform(1, 3) * axis / np.linalg.norm(axis),
        }
    elif preset == "vibration":
        params = {
            "freq_hz": rng.uniform(80, 200),
            "amp": rng.uniform(0.05, 0.15, (3, 1)) * np.array([1.0, 0.3]),
            "phase": rng.uniform(0, 2 * np.pi, (3, 2)),
        }
    elif preset == "orbit":
        azimuth = rng.uniform(0, np.pi)
        params = {
            "rate_deg_s": rng.uniform(*ORBIT_RATE_DEG_S) * rng.choice([-1.0, 1.0]),
            "axis": [np.cos(azimuth), np.sin(azimuth), 0.0],
        }
    else:
        raise ValueError(f"unknown motion {preset!r}")
    return Trajectory(preset, {k: np.asarray(v, np.float64).tolist() for k, v in params.items()})


def moved_scene(scene: Scene, rotation: np.ndarray, centre: np.ndarray) -> Scene:
    """``scene`` with its projector turned by ``rotation`` (``base_from_moved``) and moved to ``centre``.

    The world frame is the projector's, so the camera and the surface move the other way:
    ``X_moved = rotation^T (X - centre)`` for every world point ``X`` of ``scene``.
    """
    rt = rotation.T
    s = scene.surface
    surface = Surface(s.kind, rt @ s.rotation, rt @ (s.origin - centre), s.params)
    return Scene(scene.projector, scene.camera, scene.R @ rotation, rt @ (scene.C - centre), surface)


def rotation_vector(rot: np.ndarray) -> np.ndarray:
    """Axis times angle (radians) of a rotation matrix (angles below pi)."""
    angle = np.arccos(np.clip((np.trace(rot) - 1) / 2, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    w = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    return angle * w / (2 * np.sin(angle))


def _rotation_deg(rotvec_deg: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(rotvec_deg))
    return rotation_about(rotvec_deg, np.radians(angle)) if angle > 0 else np.eye(3)


def _sines(amp: list, freq: list, phase: list, t: float) -> np.ndarray:
    """Per row ``sum_j amp (sin(2 pi f t + phase) - sin(phase))``: zero at ``t = 0``."""
    a, f, ph = np.asarray(amp), np.asarray(freq), np.asarray(phase)
    return (a * (np.sin(2 * np.pi * f * t + ph) - np.sin(ph))).sum(axis=1)
