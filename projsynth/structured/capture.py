"""The virtual rig: photograph a pattern set (and content pictures) through one simulated scene.

``projsynth capture`` stands in for a projector, a surface and a camera on a tripod: one scene of the
transform table (geometry drawn once, photometry drawn once), every pattern photographed through it
with its own sensor noise, so :mod:`projsynth.structured.decode` can be measured against the exact truth. It
writes, into ``OUT``:

* one photo per pattern, named as the pattern (``NN-<name>.png``, the camera's frame, RGB);
* ``content/<stem>.png``: the photo of each ``--content`` picture (the picture is fitted to the
  projector's frame first, and written beside it as ``content/<stem>-projected.png``);
* ``truth.exr``: the exact correspondence, in the format ``decode`` writes (projector grid, camera
  pixels, ``valid`` as the shards define it);
* ``capture.json``: the scene, the drawn parameters and the seed.

Random streams: ``SeedSequence(seed, spawn_key=(2, transform))`` draws the scene, its photometry and
the transparency field; photo ``i`` draws its noise from ``(2, transform, 1, i)``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..content.procedural import render_procedural
from ..content.sources import fit_to_size
from ..dataset.transforms import TransformTable
from ..errors import ProjsynthError
from ..flow.formats import encode_flow_exr
from ..sim.photometric import BLENDS
from ..sim.render import alpha_field, camera_view, ground_truth, photograph
from ..sim.rig import make_scene
from ..sim.scene import Scene
from ..utils.files import remove_stale_temporaries, write_atomic_all
from ..utils.images import load_image, png_bytes
from ..utils.outputs import folder_files, refuse_overwriting_inputs
from ..utils.ranges import draw
from ..versions import __version__
from .patterns import PatternSet

CAPTURE_FILE, TRUTH_FILE = "capture.json", "truth.exr"
_CAPTURE = 2  # spawn-key word of the virtual rig's streams (0: samples, 1: source images)


@dataclass(frozen=True)
class Rig:
    """One simulated projector-camera pose: what every photo of a capture shares."""

    scene: Scene
    photometry: dict[str, float]
    alpha: np.ndarray  # (H, W) projector transparency field
    view: tuple[np.ndarray, np.ndarray]  # camera_view(scene)
    background: np.ndarray  # (Hc, Wc, 3) uint8
    blend: str
    params: dict


def make_rig(
    table: TransformTable,
    transform: int,
    seed: int,
    size: tuple[int, int],
    camera_size: tuple[int, int],
    blend: str = "physical",
    background: np.ndarray | None = None,
) -> Rig:
    """Draw the scene of ``transform`` for a projector of ``size`` and a camera of ``camera_size``.

    Args:
        background: the surface as the camera sees it (its albedo, for ``physical``), ``(Hc, Wc, 3)``
            uint8; None: a built-in procedural photograph drawn from the same seed.
    """
    if not 0 <= transform < len(table):
        raise ProjsynthError(f"--transform: {transform} is not an id of the table (0..{len(table) - 1})")
    if blend not in BLENDS:
        raise ProjsynthError(f"--blend: {blend!r} is not one of {', '.join(BLENDS)}")
    cfg = table.configs[transform]
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_CAPTURE, transform)))
    scene, geometry = make_scene(cfg.family, cfg.geometry, rng, size, camera_size)
    photometry = draw(rng, cfg.photometry)
    alpha = alpha_field(size, photometry["alpha"], photometry["alpha_var"], rng)
    if background is None:
        background = render_procedural("natural", "urban", camera_size, rng)
    elif background.shape[:2] != tuple(camera_size):
        background = fit_to_size(background, camera_size, "--background")
    params = {
        "transform_id": transform,
        "transform": {
            "name": cfg.name,
            "family": cfg.family,
            "severity": cfg.severity,
            "condition": cfg.condition,
            "table_version": table.version,
        },
        "geometry": geometry,
        "photometry": photometry,
        "blend": blend,
        "scene": scene.to_dict(),
    }
    return Rig(scene, photometry, alpha, camera_view(scene), background, blend, params)


def shoot(rig: Rig, image: np.ndarray, seed: int, index: int) -> np.ndarray:
    """The camera's photo ``(Hc, Wc, 3)`` uint8 of projector image ``image`` (grey or RGB, uint8)."""
    rng = np.random.default_rng(
        np.random.SeedSequence(seed, spawn_key=(_CAPTURE, rig.params["transform_id"], 1, index))
    )
    return photograph(image, rig.alpha, rig.view, rig.background, rig.photometry, rig.blend, rng)


def capture(
    patterns: PatternSet,
    out: Path,
    *,
    table: TransformTable,
    transform: int,
    seed: int = 0,
    camera_size: tuple[int, int] | None = None,
    contents: list[Path] = (),
    background: Path | None = None,
    blend: str = "physical",
    patterns_dir: Path | None = None,
) -> dict:
    """Photograph ``patterns`` and ``contents`` through one scene into ``out`` (see the module docstring).

    ``patterns_dir``: the folder ``patterns`` was read from; ``out`` may not be it (nor hold any input).

    Returns:
        The ``capture.json`` record (scene parameters, valid share of the truth, files).
    """
    out = Path(out)
    if not 0 <= seed < 2**64:  # as `gen`'s
        raise ProjsynthError(f"--seed: must be in 0..{2**64 - 1}, got {seed}")
    inputs = [("--content", Path(c)) for c in contents] + [("--background", background)]
    inputs += folder_files("--patterns", Path(patterns_dir)) if patterns_dir is not None else []
    refuse_overwriting_inputs([("--out", out)], inputs)
    camera_size = tuple(camera_size or patterns.size)
    bg = None if background is None else load_image(background)
    rig = make_rig(table, transform, seed, patterns.size, camera_size, blend, bg)
    flow, valid, _ = ground_truth(rig.scene)
    files = [(out / TRUTH_FILE, encode_flow_exr(flow, valid, f"truth-t{transform:03d}-s{seed}"))]
    for i, (name, img) in enumerate(zip(patterns.names, patterns.images(), strict=True)):
        files.append((out / f"{name}.png", png_bytes(out / name, shoot(rig, img, seed, i))))
    stems = [Path(c).stem for c in contents]
    if len(set(stems)) < len(stems):
        raise ProjsynthError("--content: two pictures share a file name stem; rename one")
    for j, path in enumerate(contents):
        picture = fit_to_size(load_image(Path(path)), patterns.size, str(path))
        photo = shoot(rig, picture, seed, len(patterns.names) + j)
        files += [
            (out / "content" / f"{stems[j]}-projected.png", png_bytes(out / stems[j], picture)),
            (out / "content" / f"{stems[j]}.png", png_bytes(out / stems[j], photo)),
        ]
    record = {
        "generator": f"projsynth {__version__}",
        "seed": seed,
        "patterns": patterns.describe(),
        "projector_size": list(patterns.size),
        "camera_size": list(camera_size),
        "background": None if background is None else str(background),
        "contents": [str(c) for c in contents],
        "valid_share": float(valid.mean()),
        **rig.params,
    }
    files.append((out / CAPTURE_FILE, (json.dumps(record, indent=1) + "\n").encode()))
    refuse_overwriting_inputs([("--out", f) for f, _ in files], inputs)
    write_atomic_all(files, make_parents=True)
    for folder in {f.parent for f, _ in files}:
        remove_stale_temporaries(folder, [f.name for f, _ in files if f.parent == folder])
    return record
