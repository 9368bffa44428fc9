"""What a dataset contains: the resolved plan, and each sample as a pure function of (plan, index).

Sample index ``k`` in ``[0, pairs * 2 * T)`` (``T`` selected transforms) maps to
``pair = k // (2T)``, ``role = (k // T) % 2``, ``transform = transforms[k % T]``. Role 0 projects the
natural image onto the generated scene, role 1 the reverse (the paper's bidirectional interchange).
Every random draw comes from ``SeedSequence(seed, spawn_key=(0, split, pair, role, transform))`` (source
images: ``(1, split, pair, kind)``), so a
sample never depends on the worker count, the shard size or which machine made it.

Sequences (``frames`` > 1, :mod:`projsynth.sim.motion`): what is a sample above becomes a sequence of
``frames`` consecutive samples, ``k = sequence * frames + frame``; the sequence draws its scene and
photometry as the sample would, its trajectory from ``(2, split, pair, role, transform)`` and each
frame's sensor noise from ``(3, split, pair, role, transform, frame)``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..content.procedural import THEMES, render_procedural
from ..content.sources import SPLITS, FolderSource, SourceImage, fit_to_size
from ..errors import ProjsynthError
from ..sim.motion import FRAME_RATE_HZ, MOTIONS, draw_trajectory, moved_scene
from ..sim.photometric import BLENDS
from ..sim.render import render
from ..sim.rig import make_scene
from ..sim.scene import Scene
from ..utils.images import load_image
from ..utils.ranges import draw
from ..versions import FORMAT_VERSION, __version__
from .transforms import TransformTable, load_table, parse_selection

ROLES = ("natural_on_generated", "generated_on_natural")
KINDS = ("natural", "generated")
MIN_SIZE, MAX_SIZE = 32, 4096
# Leading spawn-key words keep the kinds of stream apart: (SAMPLE, split, pair, role, transform),
# (SOURCE, split, pair, kind), a sequence's (MOTION, split, pair, role, transform) and its frames'
# (NOISE, split, pair, role, transform, frame) can never coincide.
_SAMPLE, _SOURCE, _MOTION, _NOISE = 0, 1, 2, 3
MAX_FRAMES = 1000


@dataclass(frozen=True)
class Plan:
    """The resolved generation config: everything that determines the samples."""

    size: tuple[int, int]
    seed: int
    split: str
    pairs: int
    transforms: tuple[int, ...]
    blend: str
    table: TransformTable
    sources: dict[str, tuple[SourceImage, ...]] | None = None  # None: built-in procedural images
    skipped: tuple[str, ...] = field(default=())  # unreadable source files, with the reason
    frames: int = 1  # > 1: every (pair, role, transform) is a sequence of this many frames
    motion: str | None = None  # the trajectory preset of sequences (projsynth.sim.motion.MOTIONS)

    @property
    def num_samples(self) -> int:
        return self.pairs * 2 * len(self.transforms) * self.frames

    def describe(self) -> dict:
        """JSON form recorded in ``dataset.json``/``manifest.json``; hashed into ``config_hash``."""
        return {
            "format_version": FORMAT_VERSION,
            "generator": f"projsynth {__version__}",
            "size": list(self.size),
            "seed": self.seed,
            "split": self.split,
            "pairs": self.pairs,
            "transforms": list(self.transforms),
            "blend": self.blend,
            "table_version": self.table.version,
            "table_digest": self.table.digest(),
            "sources": None if self.sources is None else {k: [s.name for s in v] for k, v in self.sources.items()},
        } | ({"frames": self.frames, "motion": self.motion} if self.frames > 1 else {})

    def config_hash(self) -> str:
        return plan_hash(self.describe())


# The keys of ``Plan.describe()``: what ``config_hash`` covers (a manifest's copy of them must hash to it)
PLAN_KEYS = (
    "format_version",
    "generator",
    "size",
    "seed",
    "split",
    "pairs",
    "transforms",
    "blend",
    "table_version",
    "table_digest",
    "sources",
)


# Sequence datasets add these to the plan (absent from single-frame plans, whose hash stays as it was).
SEQUENCE_KEYS = ("frames", "motion")

# A captured dataset (projsynth.structured.captured) records its capture instead of a generation config.
CAPTURED_PLAN_KEYS = ("format_version", "generator", "size", "camera_size", "split", "pairs", "blend", "captured")


def plan_hash(described: dict) -> str:
    """``config_hash``: sha256 of the ``PLAN_KEYS`` (``CAPTURED_PLAN_KEYS`` for captured data) of
    ``described`` as canonical JSON."""
    keys = CAPTURED_PLAN_KEYS if "captured" in described else PLAN_KEYS
    keys += SEQUENCE_KEYS if "frames" in described else ()
    return hashlib.sha256(json.dumps({k: described[k] for k in keys}, sort_keys=True).encode()).hexdigest()


def parse_size(text: str, option: str = "--size") -> tuple[int, int]:
    """``"384x512"`` -> ``(384, 512)`` (height x width), both in ``[32, 4096]``."""
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ProjsynthError(f"{option}: expected HxW such as 384x512, got {text!r}") from None
    if not (MIN_SIZE <= h <= MAX_SIZE and MIN_SIZE <= w <= MAX_SIZE):
        raise ProjsynthError(f"{option}: {h}x{w} is outside {MIN_SIZE}..{MAX_SIZE} per side")
    return h, w


def resolve_plan(
    *,
    size: tuple[int, int],
    seed: int,
    split: str,
    pairs: int | None,
    transforms: str | None,
    blend: str,
    table_path: Path | None = None,
    natural: Path | None = None,
    generated: Path | None = None,
    frames: int = 1,
    motion: str | None = None,
) -> Plan:
    """Validate the options and fix the source images of every pair (folders are read once here).

    ``frames`` > 1 makes sequences of the rig moving along ``motion`` (default ``hover``).
    """
    if not 1 <= frames <= MAX_FRAMES:
        raise ProjsynthError(f"--frames: must be in 1..{MAX_FRAMES}, got {frames}")
    if motion is not None and frames == 1:
        raise ProjsynthError(f"--motion {motion}: a motion needs a sequence; give --frames N with N >= 2")
    if motion is not None and motion not in MOTIONS:
        raise ProjsynthError(f"--motion: {motion!r} is not one of {', '.join(MOTIONS)}")
    seq = {"frames": frames, "motion": motion or "hover"} if frames > 1 else {}
    if split not in SPLITS:
        raise ProjsynthError(f"--split: {split!r} is not one of {', '.join(SPLITS)}")
    if blend not in BLENDS:
        raise ProjsynthError(f"--blend: {blend!r} is not one of {', '.join(BLENDS)}")
    if not 0 <= seed < 2**64:  # a shard records it as an unsigned 64-bit attribute
        raise ProjsynthError(f"--seed: must be in 0..{2**64 - 1}, got {seed}")
    if pairs is not None and pairs < 1:
        raise ProjsynthError(f"--pairs: must be >= 1, got {pairs}")
    if (natural is None) != (generated is None):
        raise ProjsynthError("--natural and --generated go together; give both folders or neither")
    table = load_table(table_path)
    selected = tuple(parse_selection(transforms, len(table)))
    if natural is None:
        return Plan(size, seed, split, pairs or 4, selected, blend, table, **seq)
    chosen: dict[str, tuple[SourceImage, ...]] = {}
    skipped: list[str] = []
    for kind, folder in (("natural", natural), ("generated", generated)):
        source = FolderSource(folder, kind, f"--{kind}")
        candidates = source.files_for_split(split, seed)
        good = []
        for src in candidates:
            if pairs is not None and len(good) == pairs:
                break
            try:
                source.load(src, size)
            except ProjsynthError as e:
                skipped.append(str(e))
                continue
            good.append(src)
        chosen[kind] = tuple(good)
    n = min(len(v) for v in chosen.values())
    if n == 0 or (pairs is not None and n < pairs):
        short = [k for k in KINDS if len(chosen[k]) == n]
        why = f"; {len(skipped)} unreadable file(s) skipped, e.g. {skipped[0]}" if skipped else ""
        fix = "add images to the folder" if n == 0 or pairs is None else "lower --pairs or add images"
        raise ProjsynthError(
            f"--{short[0]}: the {split} split has only {n} usable {short[0]} image(s) "
            f"for {pairs or 'at least 1'} pair(s){why}; {fix}"
        )
    chosen = {k: v[:n] for k, v in chosen.items()}
    return Plan(size, seed, split, n, selected, blend, table, chosen, tuple(skipped), **seq)


def sample_key(plan: Plan, k: int) -> tuple[int, int, int]:
    """Sample index -> ``(pair, role, transform_id)`` (of its sequence, with ``frames`` > 1)."""
    t, s = len(plan.transforms), k // plan.frames
    return s // (2 * t), (s // t) % 2, plan.transforms[s % t]


def sequence_id(plan: Plan, k: int) -> str:
    """``SPLIT-pPPPPP-rR-tTTT``: the id of sample ``k`` (of its sequence, with ``frames`` > 1)."""
    pair, role, tid = sample_key(plan, k)
    return f"{plan.split}-p{pair:05d}-r{role}-t{tid:03d}"


def sample_id(plan: Plan, k: int) -> str:
    """The sequence id, followed by ``-fFFF`` (the frame index) in a sequence dataset."""
    return sequence_id(plan, k) + (f"-f{k % plan.frames:03d}" if plan.frames > 1 else "")


def source_images(plan: Plan, pair: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """The (natural, generated) images of ``pair`` at the plan's size, and where they came from:
    ``{kind: (name, scene theme or None)}`` (a folder image's theme is its first subfolder, when
    that is one of ``THEMES``)."""
    if plan.sources is None:
        images, origin = [], {}
        for i, kind in enumerate(KINDS):
            ss = np.random.SeedSequence(plan.seed, spawn_key=(_SOURCE, SPLITS.index(plan.split), pair, i))
            rng = np.random.default_rng(ss)
            theme = THEMES[int(rng.integers(len(THEMES)))]
            images.append(render_procedural(kind, theme, plan.size, rng))
            origin[kind] = (f"builtin:{kind}/{theme}/{plan.split}-{pair}", theme)
        return images[0], images[1], origin
    srcs = [plan.sources[kind][pair] for kind in KINDS]
    imgs = [fit_to_size(load_image(s.path), plan.size, name=str(s.path)) for s in srcs]
    return imgs[0], imgs[1], {kind: (s.name, s.theme) for kind, s in zip(KINDS, srcs, strict=True)}


@dataclass(frozen=True)
class Sample:
    index: int
    id: str
    projected: np.ndarray  # (H, W, 3) uint8
    captured: np.ndarray  # (H, W, 3) uint8
    flow: np.ndarray  # (H, W, 2) float32, projected -> captured
    valid: np.ndarray  # (H, W) bool
    params: dict

    def content_hash(self) -> str:
        """sha256 over the id, both images, the mask, the flow and the parameters."""
        h = hashlib.sha256(self.id.encode())
        for a in (self.projected, self.captured, self.valid, self.flow):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(json.dumps(self.params, sort_keys=True).encode())
        return h.hexdigest()


@dataclass(frozen=True)
class SampleScene:
    """Everything sample ``k`` draws before it renders: its images, scene and photometry, and its
    generator in the state the renderer continues from (transparency field, then noise)."""

    projected: np.ndarray
    background: np.ndarray
    scene: Scene
    geometry: dict
    photometry: dict
    rng: np.random.Generator
    exposure: tuple[Scene, ...] = ()  # a frame's scenes over its exposure (motion blur); () for ``scene`` alone
    noise: np.random.Generator | None = None  # a frame's sensor-noise stream (None: ``rng`` continues)
    motion: dict | None = None  # a frame's ``motion`` parameters (Trajectory.describe)


def sample_scene(plan: Plan, k: int, images: tuple[np.ndarray, np.ndarray, dict] | None = None) -> SampleScene:
    """The draws of sample ``k`` up to rendering (``images``: the pair's sources, if the caller has them).

    In a sequence, ``scene`` is the frame's at mid-exposure, ``exposure`` the scenes its photo averages.
    """
    pair, role, tid = sample_key(plan, k)
    natural, generated, _ = images if images is not None else source_images(plan, pair)
    projected, background = (natural, generated) if role == 0 else (generated, natural)
    cfg = plan.table.configs[tid]
    ss = np.random.SeedSequence(plan.seed, spawn_key=(_SAMPLE, SPLITS.index(plan.split), pair, role, tid))
    rng = np.random.default_rng(ss)
    scene, geometry = make_scene(cfg.family, cfg.geometry, rng, plan.size)
    photometry = draw(rng, cfg.photometry)
    if plan.frames == 1:
        return SampleScene(projected, background, scene, geometry, photometry, rng)
    key = (SPLITS.index(plan.split), pair, role, tid)
    path = draw_trajectory(
        plan.motion, plan.frames, np.random.default_rng(np.random.SeedSequence(plan.seed, spawn_key=(_MOTION, *key)))
    )
    frame = k % plan.frames
    t = frame / FRAME_RATE_HZ
    noise = np.random.default_rng(np.random.SeedSequence(plan.seed, spawn_key=(_NOISE, *key, frame)))
    offsets = path.exposure()
    exposure = tuple(moved_scene(scene, *path.pose(t + dt)) for dt in offsets) if len(offsets) > 1 else ()
    return SampleScene(
        projected,
        background,
        moved_scene(scene, *path.pose(t)),
        geometry,
        photometry,
        rng,
        exposure,
        noise,
        path.describe(t),
    )


def make_sample(plan: Plan, k: int, images: tuple[np.ndarray, np.ndarray, dict] | None = None) -> Sample:
    """Render sample ``k`` of ``plan`` (``images``: the pair's sources, if the caller has them)."""
    pair, role, tid = sample_key(plan, k)
    images = images if images is not None else source_images(plan, pair)
    origin = images[2]
    cfg = plan.table.configs[tid]
    s = sample_scene(plan, k, images)
    projected, scene, geometry, photometry = s.projected, s.scene, s.geometry, s.photometry
    out = render(projected, s.background, scene, photometry, plan.blend, s.rng, exposure=s.exposure, noise=s.noise)
    params = {
        "sample_id": sample_id(plan, k),
        "pair": pair,
        "role": ROLES[role],
        "transform_id": tid,
        "transform": {
            "name": cfg.name,
            "family": cfg.family,
            "severity": cfg.severity,
            "condition": cfg.condition,
            "table_version": plan.table.version,
        },
        "sources": {
            "projected": origin[KINDS[role]][0],
            "background": origin[KINDS[1 - role]][0],
            "projected_theme": origin[KINDS[role]][1],
            "background_theme": origin[KINDS[1 - role]][1],
        },
        "geometry": geometry,
        "photometry": photometry,
        "blend": plan.blend,
        "scene": scene.to_dict(),
        "stats": out.stats,
    }
    if plan.frames > 1:
        params |= {
            "sequence": sequence_id(plan, k),
            "frame": k % plan.frames,
            "frames": plan.frames,
            "motion": s.motion,
        }
    return Sample(k, params["sample_id"], projected, out.captured, out.flow, out.valid, params)
